#!/bin/sh
# The showcase's scripted orders (issue 17), each given while the robot moves: teleop, then
# waypoints, then a goal, then reach beacon (through a dark patch where "Track beacon" moves to
# the histogram tracker and back), then waypoints to the north wall and follow wall, then stop. The same sequence is the
# system test `showcase::the_showcase_switches_orders_of_every_kind_while_the_robot_moves`.
# Start the system first, from the repository's root:
#
#     hng run --no-gui examples/showcase/launch.toml &
#     examples/showcase/orders.sh
#
# HNG (default: hng on PATH) and HNG_PREFIX select the binary and the system. Each `hng order`
# waits for the Interface's answer and exits 1 when it is refused (this script then stops);
# every wait is on a condition (the order's end, an offered behaviour), with a deadline.
set -eu
HNG=${HNG:-hng}
say() { printf '\n== %s\n' "$*"; }
# wait_for SECONDS WHAT COMMAND...: runs COMMAND every 0.25 s until it succeeds.
wait_for() {
    n=$(($1 * 4)); what=$2; shift 2
    until "$@"; do
        n=$((n - 1))
        if [ "$n" -le 0 ]; then
            echo "timed out waiting for $what" >&2
            exit 1
        fi
        sleep 0.25
    done
}
offered() { $HNG behaviours --once --json 2>/dev/null | grep -q "$1"; }
in_force() { $HNG order show --json | grep -q '"active":true'; }
# near X Y D: the robot's true pose (the simulator's ground truth) within D m of (X, Y).
near() {
    $HNG topic echo sim/ground_truth --count 1 --timeout 2 --json |
        sed -n 's/.*"x":\([-0-9.e]*\),"y":\([-0-9.e]*\),.*/\1 \2/p' |
        awk -v x="$1" -v y="$2" -v d="$3" '{ exit !(($1 - x) ^ 2 + ($2 - y) ^ 2 < d * d) }'
}
# drive JSON: publishes the teleop command at 10 Hz in the background until `halt`.
drive() {
    $HNG topic pub hng/teleop "$1" --rate 10 >/dev/null &
    DRIVE=$!
}
halt() { kill "$DRIVE" 2>/dev/null || true; wait "$DRIVE" 2>/dev/null || true; }
trap halt EXIT
DRIVE=
WALL='"kind":"follow_wall","param":-1'
BEACON='"kind":"reach_beacon","param":3'

wait_for 60 "the system (the Interface's behaviours)" offered '"kind":"teleop"'

say "teleop: forward (the deadman stops the robot if the commands stop)"
$HNG order teleop
drive '{"linear_x": 0.3}'
sleep 1

say "waypoints along the south wall, given while teleop drives"
$HNG order waypoints 6,1 13,1
halt
wait_for 120 "follow wall right offered" offered "$WALL"
$HNG behaviours --once

say "a goal past the partition, given while the robot is still on its waypoints"
in_force
$HNG order goal 17,4.5
wait_for 180 "the goal reached" sh -c "! $HNG order show --json | grep -q '\"active\":true'"

say "turn under teleop until a tracker sees beacon 3, then reach it while turning"
$HNG order teleop
drive '{"linear_x": 0.1, "angular_z": 0.6}'
wait_for 120 "reach beacon 3 offered" offered "$BEACON"
$HNG order reach-beacon 3
halt
$HNG contracts | grep -i "track beacon" || true
wait_for 180 "beacon 3 reached (the robot within 0.5 m of it)" near 17.5 8 0.5
sleep 1
$HNG contracts | grep -i "track beacon" || true

say "waypoints west along the north wall, then follow it on the right while moving"
# (Turning by teleop until the robot faces west overshot: the script polls the pose by
# starting a process, slower than the simulated turn; waypoints put it there on a condition.)
$HNG order waypoints 16.5,9.3 12,9.3
wait_for 120 "follow wall right offered by the north wall" offered "$WALL"
$HNG order follow-wall right
wait_for 60 "the robot 2 m along the north wall" sh -c "$HNG topic echo sim/ground_truth --count 1 --timeout 2 --json | grep -q '\"x\":1[0-4]\\.'"

say "stop, while following"
$HNG order stop
$HNG order show
