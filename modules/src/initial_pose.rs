//! The operator's pose estimates (ROS `/initialpose`, RViz's "2D Pose Estimate"): a
//! `PoseWithCovariance` in `map` on [`INITIAL_POSE_CHANNEL`], from `hng topic pub`, a tool
//! or the evaluation harness after it moved the simulated robot. Localization restarts its
//! filter there and SLAM starts a new map there.
//!
//! The channel is a state channel (a late joiner gets the latest estimate), so a module that
//! restarts would see the last estimate again: the checkpoint keeps the identity (publisher,
//! sequence number) of the estimate last applied ([`InitialPoseInput::applied`]), and that
//! one is not applied twice. An estimate that is not finite, not in `map` or whose
//! covariance is not a covariance is refused with a warning and counted.

use hng_runtime::channel::InputId;
use hng_runtime::msg::{FrameId, PoseWithCovariance};
use hng_runtime::{Context, ModuleResult, Subscriber};
use serde::{Deserialize, Serialize};

pub use hng_runtime::msg::INITIAL_POSE_CHANNEL;

/// Variances given to an estimate that says nothing of its uncertainty (an all-zero
/// covariance): σ 0.1 m in x and y, 0.05 rad in heading.
const DEFAULT_VARIANCES: [f64; 3] = [0.01, 0.01, 0.0025];

/// Which estimate a module applied last: its publisher's id and sequence number.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct EstimateId {
    /// [`hng_runtime::msg::Header::source`].
    pub source: u32,
    /// [`hng_runtime::msg::Header::seq`].
    pub seq: u64,
}

impl EstimateId {
    /// The identity of estimate `p`.
    pub fn of(p: &PoseWithCovariance) -> EstimateId {
        EstimateId {
            source: p.header.source,
            seq: p.header.seq,
        }
    }
}

/// Why an estimate was refused.
pub fn check(p: &PoseWithCovariance) -> Result<(), &'static str> {
    if p.header.frame_id != FrameId::MAP {
        return Err("not in the map frame");
    }
    if ![p.pose.x, p.pose.y, p.pose.theta]
        .iter()
        .all(|v| v.is_finite())
    {
        return Err("a non-finite pose");
    }
    let c = &p.covariance;
    if !c.iter().all(|v| v.is_finite()) {
        return Err("a non-finite covariance");
    }
    if [c[0], c[4], c[8]].iter().any(|v| *v < 0.0) {
        return Err("a negative variance");
    }
    Ok(())
}

/// The estimate with a usable covariance: an all-zero one gets [`DEFAULT_VARIANCES`].
pub fn with_default_covariance(mut p: PoseWithCovariance) -> PoseWithCovariance {
    if p.covariance.iter().all(|v| *v == 0.0) {
        p.covariance[0] = DEFAULT_VARIANCES[0];
        p.covariance[4] = DEFAULT_VARIANCES[1];
        p.covariance[8] = DEFAULT_VARIANCES[2];
    }
    p
}

/// A module's input of operator pose estimates.
#[derive(Debug)]
pub struct InitialPoseInput {
    sub: Subscriber<PoseWithCovariance>,
    applied: Option<EstimateId>,
    refused: u64,
}

impl InitialPoseInput {
    /// Subscribes to `channel` (none when empty: the module takes no estimates).
    pub fn new(ctx: &mut Context, channel: &str) -> ModuleResult<Option<InitialPoseInput>> {
        if channel.is_empty() {
            return Ok(None);
        }
        Ok(Some(InitialPoseInput {
            sub: ctx.subscribe(channel, None)?,
            applied: None,
            refused: 0,
        }))
    }

    /// Whether `input` is this one.
    pub fn is(&self, input: InputId) -> bool {
        input == self.sub.id()
    }

    /// The newest valid estimate that was not applied yet (it counts as applied from now
    /// on, and is logged with `applied`: what the module does with it); invalid ones are
    /// refused, logged and counted.
    pub fn take(
        &mut self,
        module: &str,
        applied: &str,
    ) -> ModuleResult<Option<PoseWithCovariance>> {
        let mut newest = None;
        while let Some(s) = self.sub.receive()? {
            let id = EstimateId::of(&s);
            if self.applied == Some(id) {
                continue;
            }
            match check(&s) {
                Ok(()) => newest = Some((id, with_default_covariance(*s))),
                Err(why) => {
                    self.refused += 1;
                    tracing::warn!(
                        module,
                        refused = self.refused,
                        "initial pose refused: {why}"
                    );
                }
            }
        }
        Ok(newest.map(|(id, p)| {
            self.applied = Some(id);
            tracing::info!(
                module,
                x = p.pose.x,
                y = p.pose.y,
                theta = p.pose.theta,
                "{applied}"
            );
            p
        }))
    }

    /// The estimate applied last (for the checkpoint).
    pub fn applied(&self) -> Option<EstimateId> {
        self.applied
    }

    /// After a restart: the estimate the checkpoint says was applied is not applied again.
    pub fn restore(&mut self, applied: Option<EstimateId>) {
        self.applied = applied;
    }

    /// Estimates refused so far.
    pub fn refused(&self) -> u64 {
        self.refused
    }
}

/// Notices the operator's new pose estimates without applying them: a client whose provider
/// will jump to the estimate (the Servo does not blame its Localization provider for that
/// jump). A polled input: read when the module runs anyway.
#[derive(Debug)]
pub struct EstimateNotice {
    sub: Subscriber<PoseWithCovariance>,
    seen: Option<EstimateId>,
}

impl EstimateNotice {
    /// Polls `channel` (none when empty).
    pub fn new(ctx: &mut Context, channel: &str) -> ModuleResult<Option<EstimateNotice>> {
        if channel.is_empty() {
            return Ok(None);
        }
        Ok(Some(EstimateNotice {
            sub: ctx.subscribe_polled(channel)?,
            seen: None,
        }))
    }

    /// Whether an estimate came that was not seen before (the latest one a module started
    /// with counts too: a restarted client holds its judgement once).
    pub fn new_estimate(&mut self) -> ModuleResult<bool> {
        let Some(s) = self.sub.latest()? else {
            return Ok(false);
        };
        let id = EstimateId::of(&s);
        Ok(self.seen.replace(id) != Some(id))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::msg::{Header, Pose2D};

    fn estimate(x: f64, frame: FrameId) -> PoseWithCovariance {
        PoseWithCovariance {
            header: Header {
                frame_id: frame,
                ..Header::default()
            },
            pose: Pose2D::new(x, 2.0, 0.5),
            covariance: [0.0; 9],
        }
    }

    #[test]
    fn estimates_outside_the_map_frame_or_not_finite_are_refused_with_their_reason() {
        assert_eq!(check(&estimate(1.0, FrameId::MAP)), Ok(()));
        assert_eq!(
            check(&estimate(1.0, FrameId::ODOM)),
            Err("not in the map frame")
        );
        assert_eq!(
            check(&estimate(f64::NAN, FrameId::MAP)),
            Err("a non-finite pose")
        );
        let mut p = estimate(1.0, FrameId::MAP);
        p.covariance[4] = -1.0;
        assert_eq!(check(&p), Err("a negative variance"));
        p.covariance[4] = f64::INFINITY;
        assert_eq!(check(&p), Err("a non-finite covariance"));
    }

    #[test]
    fn an_estimate_without_covariance_gets_the_default_one_and_a_given_one_is_kept() {
        let p = with_default_covariance(estimate(1.0, FrameId::MAP));
        assert_eq!(
            [p.covariance[0], p.covariance[4], p.covariance[8]],
            DEFAULT_VARIANCES
        );
        let mut q = estimate(1.0, FrameId::MAP);
        q.covariance[0] = 0.5;
        assert_eq!(with_default_covariance(q).covariance, q.covariance);
    }
}
