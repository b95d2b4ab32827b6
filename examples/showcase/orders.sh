#!/bin/sh
# The showcase's scripted orders (issue 17), given while the robot moves: teleop, waypoints, a
# goal, reach beacon, follow wall. Start the system first, from the repository's root:
#
#     hng run examples/showcase/launch.toml &
#     examples/showcase/orders.sh
#
# HNG (default: hng on PATH) and HNG_PREFIX select the binary and the system. Each `hng order`
# waits for the Interface's answer and exits 1 when it is refused (this script then stops).
set -eu
HNG=${HNG:-hng}
say() { printf '\n== %s\n' "$*"; }

say "teleop: forward and a little left for 3 s (the deadman stops the robot after)"
$HNG order teleop
timeout 3 $HNG topic pub hng/teleop '{"linear_x": 0.3, "angular_z": 0.1}' --rate 10 || true

say "waypoints along the south wall: attention now offers follow-wall right"
$HNG order waypoints 6,1 13,1
sleep 8
$HNG behaviours --once

say "a goal past the partition, given while the robot is still on its waypoints"
$HNG order goal 17,4.5
sleep 15

say "reach beacon 3 (offered once a tracker sees it; turn under teleop until then)"
until $HNG order reach-beacon 3 2>/dev/null; do
    $HNG order teleop >/dev/null
    timeout 1 $HNG topic pub hng/teleop '{"angular_z": 0.6}' --rate 10 || true
done
sleep 20

say "follow the east wall on the right"
$HNG order teleop >/dev/null
timeout 2 $HNG topic pub hng/teleop '{"angular_z": -0.8}' --rate 10 || true
$HNG order follow-wall right || $HNG behaviours --once
sleep 20
$HNG order show
