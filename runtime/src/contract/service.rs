//! Service descriptions: what a module provides and what it needs (paper, 4.2
//! and Table 1).

use serde::{Deserialize, Serialize};

use super::ModuleId;

/// Maximum length in bytes of a service name.
pub const MAX_SERVICE_LEN: usize = 64;
/// Maximum length in bytes of a data channel name or a data type name.
pub const MAX_CHANNEL_LEN: usize = 128;

/// A service a module provides.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ServiceOffer {
    /// Service name, e.g. `"Localization"`.
    pub service: String,
    /// Name of the type of the data published for it, e.g. `"Position"`
    /// (empty when the service is a function rather than data).
    pub data_type: String,
    /// Data channel the data will come on; empty means the default
    /// `"<module id>/<service>"` (see [`ServiceOffer::channel_for`]).
    pub channel: String,
}

impl ServiceOffer {
    /// An offer with the default data channel.
    pub fn new(service: impl Into<String>, data_type: impl Into<String>) -> Self {
        Self {
            service: service.into(),
            data_type: data_type.into(),
            channel: String::new(),
        }
    }

    /// The data channel announced in proposals by module `id`.
    pub fn channel_for(&self, id: ModuleId) -> String {
        if self.channel.is_empty() {
            format!("{}/{}", id.0, self.service)
        } else {
            self.channel.clone()
        }
    }
}

/// Whether a need is indispensable (paper, 4.2: "the needs with the lowest
/// priorities are not indispensable to obtain `f_m = 1` but they can have an
/// effect on the working quality").
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Requirement {
    /// Without a provider the module cannot work: it refuses queries and
    /// cancels its client contracts.
    Required,
    /// Without a provider the module still works, but its quality `Q` used in
    /// its value is lowered by `penalty` (clamped to `[0, 2]`).
    Optional {
        /// Amount subtracted from `Q` while the need is known unmet.
        penalty: f64,
    },
}

/// A service a module needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NeedSpec {
    /// Name of the needed service.
    pub service: String,
    /// Rank `i >= 1`, unique within the module: the contract for this need
    /// gets priority `P(module).i`. For the Manager, the rank is the
    /// objective's place in the mission (1 = most important).
    pub rank: u16,
    /// Required or optional.
    pub requirement: Requirement,
}

impl NeedSpec {
    /// A required need.
    pub fn required(service: impl Into<String>, rank: u16) -> Self {
        Self {
            service: service.into(),
            rank,
            requirement: Requirement::Required,
        }
    }

    /// An optional need lowering `Q` by `penalty` while unmet.
    pub fn optional(service: impl Into<String>, rank: u16, penalty: f64) -> Self {
        Self {
            service: service.into(),
            rank,
            requirement: Requirement::Optional { penalty },
        }
    }

    /// True for [`Requirement::Required`].
    pub fn is_required(&self) -> bool {
        matches!(self.requirement, Requirement::Required)
    }
}

/// Errors in a service description.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ServiceError {
    /// A name is empty, too long or contains control characters.
    #[error("invalid {what} {name:?}: must be 1..={max} bytes without control characters")]
    BadName {
        /// What kind of name.
        what: &'static str,
        /// The name.
        name: String,
        /// Maximum length.
        max: usize,
    },
    /// Two needs share a rank.
    #[error("needs {first:?} and {second:?} both have rank {rank}: ranks must be unique")]
    DuplicateRank {
        /// The rank.
        rank: u16,
        /// First need.
        first: String,
        /// Second need.
        second: String,
    },
    /// A rank is 0.
    #[error("need {service:?} has rank 0: ranks start at 1")]
    ZeroRank {
        /// The need.
        service: String,
    },
    /// The same service is offered twice.
    #[error("service {service:?} is provided twice")]
    DuplicateOffer {
        /// The service.
        service: String,
    },
    /// An optional penalty is NaN.
    #[error("need {service:?} has a NaN penalty")]
    BadPenalty {
        /// The need.
        service: String,
    },
}

pub(crate) fn check_name(what: &'static str, name: &str, max: usize) -> Result<(), ServiceError> {
    if name.is_empty() || name.len() > max || name.chars().any(char::is_control) {
        return Err(ServiceError::BadName {
            what,
            name: name.chars().take(max + 8).collect(),
            max,
        });
    }
    Ok(())
}

/// Validates offers and needs (names, unique ranks >= 1, no duplicate offer).
///
/// # Errors
/// The first [`ServiceError`] found.
pub fn validate_description(
    provides: &[ServiceOffer],
    needs: &[NeedSpec],
) -> Result<(), ServiceError> {
    for (i, o) in provides.iter().enumerate() {
        check_name("service name", &o.service, MAX_SERVICE_LEN)?;
        if !o.data_type.is_empty() {
            check_name("data type", &o.data_type, MAX_CHANNEL_LEN)?;
        }
        if !o.channel.is_empty() {
            check_name("channel name", &o.channel, MAX_CHANNEL_LEN)?;
        }
        if provides[..i].iter().any(|p| p.service == o.service) {
            return Err(ServiceError::DuplicateOffer {
                service: o.service.clone(),
            });
        }
    }
    for (i, n) in needs.iter().enumerate() {
        check_name("service name", &n.service, MAX_SERVICE_LEN)?;
        if n.rank == 0 {
            return Err(ServiceError::ZeroRank {
                service: n.service.clone(),
            });
        }
        if let Requirement::Optional { penalty } = n.requirement
            && penalty.is_nan()
        {
            return Err(ServiceError::BadPenalty {
                service: n.service.clone(),
            });
        }
        if let Some(other) = needs[..i].iter().find(|o| o.rank == n.rank) {
            return Err(ServiceError::DuplicateRank {
                rank: n.rank,
                first: other.service.clone(),
                second: n.service.clone(),
            });
        }
    }
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // Tests may unwrap.
mod tests {
    use super::*;

    #[test]
    fn contract_service_validation() {
        let offers = [ServiceOffer::new("Localization", "Position")];
        let needs = [
            NeedSpec::required("Odometry", 1),
            NeedSpec::optional("LIDAR data", 2, 0.2),
        ];
        assert_eq!(validate_description(&offers, &needs), Ok(()));
        assert!(matches!(
            validate_description(
                &offers,
                &[NeedSpec::required("A", 1), NeedSpec::required("B", 1)]
            ),
            Err(ServiceError::DuplicateRank { rank: 1, .. })
        ));
        assert!(matches!(
            validate_description(&offers, &[NeedSpec::required("A", 0)]),
            Err(ServiceError::ZeroRank { .. })
        ));
        assert!(matches!(
            validate_description(&[ServiceOffer::new("", "")], &[]),
            Err(ServiceError::BadName { .. })
        ));
        let long = "x".repeat(MAX_SERVICE_LEN + 1);
        assert!(validate_description(&[ServiceOffer::new(long, "")], &[]).is_err());
        assert!(matches!(
            validate_description(&[offers[0].clone(), offers[0].clone()], &[]),
            Err(ServiceError::DuplicateOffer { .. })
        ));
        assert_eq!(offers[0].channel_for(ModuleId(7)), "7/Localization");
    }
}
