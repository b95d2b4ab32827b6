//! Messages the navigation modules add to the runtime's set (`hng_runtime::msg`).
//!
//! Same rules as the runtime's messages: `#[repr(C)]`, [`ZeroCopySend`], a versioned type name
//! (`hng-modules/<Name>/v<N>`), a [`Header`] first, REP-103 units.

use hng_runtime::msg::{Header, Pose2D};
use hng_runtime::qos::ChannelKind;
use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

/// Largest number of goals one [`Mission`] message carries.
pub const MAX_MISSION_GOALS: usize = 32;

/// Where a goal stands.
#[repr(u8)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, strum::FromRepr)]
#[serde(rename_all = "snake_case")]
pub enum GoalState {
    /// Nothing known (no goal).
    #[default]
    Idle = 0,
    /// Being pursued.
    Active = 1,
    /// Reached within its tolerance.
    Reached = 2,
    /// Refused: out of the map, or unreachable (see the reporter's log for why).
    Refused = 3,
}

/// The progress of a goal, reported by the Servo-controller (reached) and Planning (refused).
/// A state channel: late joiners get the latest.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-modules/GoalStatus/v2")]
pub struct GoalStatus {
    /// Header; `frame_id` is `map`.
    pub header: Header,
    /// The goal this is about ([`hng_runtime::msg::Goal::id`]).
    pub goal_id: u32,
    /// A [`GoalState`] as a byte.
    pub state: u8,
    /// Distance left to the goal (straight line for the servo, path length for planning), m;
    /// negative if unknown.
    pub distance_m: f64,
    /// Why a goal was refused: a [`RefusalReason`] as a byte (0 otherwise).
    pub reason: u8,
}

impl GoalStatus {
    /// The state.
    pub fn goal_state(&self) -> GoalState {
        GoalState::from_repr(self.state).unwrap_or_default()
    }

    /// Why the goal was refused, if it was.
    pub fn refusal_reason(&self) -> Option<RefusalReason> {
        RefusalReason::from_repr(self.reason)
    }
}

/// Why Planning refused a goal ([`GoalStatus::reason`]).
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, strum::FromRepr)]
#[serde(rename_all = "snake_case")]
pub enum RefusalReason {
    /// Outside the known map.
    OutsideMap = 1,
    /// Inside an obstacle, or closer to one than the robot's radius and clearance.
    InObstacle = 2,
    /// No path to it in the known map.
    Unreachable = 3,
    /// A non-finite position.
    Invalid = 4,
    /// No progress toward it, and the recovery behaviours did not help (Planning's progress
    /// checker; the reason in words is on `planning/progress` and in its log).
    Stuck = 5,
}

impl RefusalReason {
    /// In words.
    pub fn describe(self) -> &'static str {
        match self {
            RefusalReason::OutsideMap => "outside the map",
            RefusalReason::InObstacle => "inside an obstacle",
            RefusalReason::Unreachable => "unreachable",
            RefusalReason::Invalid => "not a finite position",
            RefusalReason::Stuck => "no progress: stuck after every recovery behaviour",
        }
    }
}

hng_runtime::impl_message!(GoalStatus, ChannelKind::State);

/// One goal of a mission.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize, Deserialize)]
pub struct MissionGoal {
    /// Target pose in `map` (theta used only if `use_theta` is 1).
    pub pose: Pose2D,
    /// Position tolerance, m.
    pub tolerance_m: f64,
    /// 1 if the final heading matters.
    pub use_theta: u8,
}

/// What a [`Mission`] message does to the Manager's goal list.
#[repr(u8)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, strum::FromRepr)]
#[serde(rename_all = "snake_case")]
pub enum MissionOp {
    /// Replace the goals (the current goal is abandoned).
    #[default]
    Replace = 0,
    /// Append the goals after the existing ones.
    Append = 1,
    /// Drop every goal: the robot holds its position.
    Clear = 2,
    /// Skip the current goal.
    Skip = 3,
}

/// A change of mission, sent to the Manager on `hng/mission` (a command channel: every
/// message counts, none is replayed to late joiners).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-modules/Mission/v1")]
pub struct Mission {
    /// Header.
    pub header: Header,
    /// A [`MissionOp`] as a byte.
    pub op: u8,
    /// Number of valid entries in `goals`.
    pub count: u32,
    /// The goals; only the first `count` are meaningful.
    pub goals: [MissionGoal; MAX_MISSION_GOALS],
}

impl Mission {
    /// The meaningful goals.
    pub fn goals(&self) -> &[MissionGoal] {
        &self.goals[..(self.count as usize).min(MAX_MISSION_GOALS)]
    }

    /// A message doing `op` with `goals` (cut at [`MAX_MISSION_GOALS`]).
    pub fn new(op: MissionOp, goals: &[MissionGoal]) -> Mission {
        let mut m = Mission {
            op: op as u8,
            ..Default::default()
        };
        let n = goals.len().min(MAX_MISSION_GOALS);
        m.goals[..n].copy_from_slice(&goals[..n]);
        m.count = n as u32;
        m
    }
}

hng_runtime::impl_message!(Mission, ChannelKind::Command);

/// The Manager's mission progress (state channel).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend, Serialize)]
#[type_name("hng-modules/MissionStatus/v1")]
pub struct MissionStatus {
    /// Header.
    pub header: Header,
    /// Goals in the mission (reached, refused and pending).
    pub goals_total: u32,
    /// Goals reached.
    pub goals_reached: u32,
    /// Goals refused (unreachable or out of the map) and skipped.
    pub goals_refused: u32,
    /// Index of the current goal in the mission; `goals_total` when done.
    pub current: u32,
    /// Id of the current goal (0 when none).
    pub current_goal_id: u32,
    /// 1 when every goal has been dealt with.
    pub done: u8,
}

hng_runtime::impl_message!(MissionStatus, ChannelKind::State);
