//! Hierarchical priorities of contracts and modules (paper, section 5.5).
//!
//! See the module documentation of [`crate::contract`] for the rules.

use std::cmp::Ordering;
use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Maximum number of components of a [`Priority`].
///
/// Every level of the contract tree adds one component, so this is also the
/// maximum depth of a contract tree. A module whose priority already has this
/// many components cannot query its needs and refuses queries with
/// [`crate::contract::Reason::TooDeep`]. The bound keeps wire messages small and
/// stops a (transient) contract cycle from growing priorities forever.
pub const MAX_DEPTH: usize = 24;

/// A hierarchical priority `P1.P2.….Pk` (paper, section 5.5).
///
/// Components are integers `>= 1`. Priorities compare lexicographically and a
/// **smaller** priority is **more important**: `1.2.5` beats `1.3.2`, `1.1`
/// beats `2`. A priority is more important than all its extensions: `1.2`
/// beats `1.2.1` (the client beats the contracts it derived for its own
/// needs). [`Priority::ROOT`] (no component, displayed `root`) is the
/// Manager's own priority and beats everything.
///
/// The type is `Copy` and allocation-free (at most [`MAX_DEPTH`] components).
#[derive(Clone, Copy)]
pub struct Priority {
    len: u8,
    parts: [u16; MAX_DEPTH],
}

/// Why a priority could not be built or parsed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PriorityError {
    /// The text was empty.
    #[error("empty priority: expected dotted integers such as \"1.2.5\" (or \"root\")")]
    Empty,
    /// A component is not an integer in `1..=65535`.
    #[error(
        "invalid priority component {component:?} at position {position} in {text:?}: expected an integer in 1..=65535"
    )]
    BadComponent {
        /// The whole text being parsed.
        text: String,
        /// 1-based position of the bad component.
        position: usize,
        /// The offending component.
        component: String,
    },
    /// A component is zero (components, like need ranks and objective numbers, start at 1).
    #[error("priority component {position} is 0: components start at 1")]
    Zero {
        /// 1-based position of the zero component.
        position: usize,
    },
    /// More than [`MAX_DEPTH`] components.
    #[error("priority has {depth} components, more than the maximum {MAX_DEPTH}")]
    TooDeep {
        /// Number of components requested.
        depth: usize,
    },
}

impl Priority {
    /// The Manager's priority: no component, more important than any other.
    pub const ROOT: Priority = Priority {
        len: 0,
        parts: [0; MAX_DEPTH],
    };

    /// Builds a priority from its components.
    ///
    /// # Errors
    /// [`PriorityError::Zero`] if a component is 0, [`PriorityError::TooDeep`]
    /// if there are more than [`MAX_DEPTH`] components.
    pub fn new(parts: &[u16]) -> Result<Self, PriorityError> {
        if parts.len() > MAX_DEPTH {
            return Err(PriorityError::TooDeep { depth: parts.len() });
        }
        let mut p = Priority::ROOT;
        for (i, &c) in parts.iter().enumerate() {
            if c == 0 {
                return Err(PriorityError::Zero { position: i + 1 });
            }
            p.parts[i] = c;
        }
        // Lossless: parts.len() <= MAX_DEPTH < 256.
        p.len = parts.len() as u8;
        Ok(p)
    }

    /// Priority of the Manager's `k`-th objective (1-based, mission order): `k`.
    ///
    /// # Errors
    /// [`PriorityError::Zero`] if `k == 0`.
    pub fn objective(k: u16) -> Result<Self, PriorityError> {
        Priority::ROOT.child(k)
    }

    /// `self.i`: the priority of the contract for the `i`-th need of a module
    /// whose priority is `self` (paper, eq. in 5.5: `P(r_i) = P(m).i`).
    ///
    /// # Errors
    /// [`PriorityError::Zero`] if `i == 0`, [`PriorityError::TooDeep`] if
    /// `self` already has [`MAX_DEPTH`] components.
    pub fn child(&self, i: u16) -> Result<Self, PriorityError> {
        if i == 0 {
            return Err(PriorityError::Zero {
                position: self.len() + 1,
            });
        }
        if self.len() >= MAX_DEPTH {
            return Err(PriorityError::TooDeep {
                depth: self.len() + 1,
            });
        }
        let mut p = *self;
        p.parts[self.len()] = i;
        p.len += 1;
        Ok(p)
    }

    /// The components, most significant first.
    pub fn parts(&self) -> &[u16] {
        &self.parts[..self.len()]
    }

    /// Number of components (0 for [`Priority::ROOT`]).
    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    /// True for [`Priority::ROOT`].
    pub fn is_root(&self) -> bool {
        self.len == 0
    }

    /// True for [`Priority::ROOT`] (no component).
    pub fn is_empty(&self) -> bool {
        self.is_root()
    }

    /// True when `self` is strictly more important than `other`.
    pub fn beats(&self, other: &Priority) -> bool {
        self < other
    }

    /// True when `self` is `ancestor` or one of its extensions.
    pub fn descends_from(&self, ancestor: &Priority) -> bool {
        self.len() >= ancestor.len() && self.parts()[..ancestor.len()] == *ancestor.parts()
    }

    /// Degraded-mode admission (paper, section 5.3): is a contract of priority
    /// `self` still served when the Resource Manager announces the minimum
    /// priority `min`?
    ///
    /// `self` is cut to the depth of `min` and compared: admitted iff the cut
    /// is at least as important as `min`. So `min = 2` keeps the whole
    /// subtrees of objectives 1 and 2 (`2.2.1.1` is admitted, the needs of an
    /// admitted module stay admitted) and sheds objective 3; `min = 2.1` keeps
    /// `1.*`, `2`, `2.1.*` and sheds `2.2.*`.
    pub fn admitted_by(&self, min: &Priority) -> bool {
        let cut = self.len().min(min.len());
        let mut truncated = *self;
        // Lossless: cut <= MAX_DEPTH.
        truncated.len = cut as u8;
        truncated <= *min
    }

    /// The most important priority of an iterator (paper: `max_i P(s_i)`),
    /// `None` if empty. This is how a module's priority derives from its
    /// client contracts.
    pub fn most_important<I: IntoIterator<Item = Priority>>(iter: I) -> Option<Priority> {
        iter.into_iter().min()
    }
}

impl PartialEq for Priority {
    fn eq(&self, other: &Self) -> bool {
        self.parts() == other.parts()
    }
}
impl Eq for Priority {}

impl std::hash::Hash for Priority {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.parts().hash(state);
    }
}

impl Ord for Priority {
    /// Lexicographic on the components; a prefix sorts first (is more important).
    fn cmp(&self, other: &Self) -> Ordering {
        self.parts().cmp(other.parts())
    }
}
impl PartialOrd for Priority {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl fmt::Display for Priority {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_dotted(f, self.parts())
    }
}

fn write_dotted(f: &mut fmt::Formatter<'_>, parts: &[u16]) -> fmt::Result {
    if parts.is_empty() {
        return f.write_str("root");
    }
    for (i, c) in parts.iter().enumerate() {
        if i > 0 {
            f.write_str(".")?;
        }
        write!(f, "{c}")?;
    }
    Ok(())
}

/// Priority components as [`Priority`] displays them (`1.2.5`, `root` when empty), for the
/// raw components of wire tables, which may hold values [`Priority::new`] refuses.
pub fn dotted(parts: &[u16]) -> String {
    struct Dotted<'a>(&'a [u16]);
    impl fmt::Display for Dotted<'_> {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            write_dotted(f, self.0)
        }
    }
    Dotted(parts).to_string()
}

impl fmt::Debug for Priority {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Priority({self})")
    }
}

impl FromStr for Priority {
    type Err = PriorityError;

    /// Parses `"1.2.5"` (or `"root"`). Whitespace around the text is ignored.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let text = s.trim();
        if text.is_empty() {
            return Err(PriorityError::Empty);
        }
        if text == "root" {
            return Ok(Priority::ROOT);
        }
        let mut parts = Vec::new();
        for (i, comp) in text.split('.').enumerate() {
            let bad = || PriorityError::BadComponent {
                text: text.to_owned(),
                position: i + 1,
                component: comp.to_owned(),
            };
            if comp.is_empty() || !comp.bytes().all(|b| b.is_ascii_digit()) {
                return Err(bad());
            }
            let v: u16 = comp.parse().map_err(|_| bad())?;
            parts.push(v);
        }
        Priority::new(&parts)
    }
}

impl Serialize for Priority {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.parts().serialize(serializer)
    }
}

impl<'de> Deserialize<'de> for Priority {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let parts: Vec<u16> = Vec::deserialize(deserializer)?;
        Priority::new(&parts).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // Tests may unwrap.
mod tests {
    use super::*;

    fn p(s: &str) -> Priority {
        s.parse().unwrap()
    }

    #[test]
    fn contract_priority_paper_order() {
        assert!(p("1.2.5").beats(&p("1.3.2")));
        assert!(p("1.1").beats(&p("2.1")));
        assert!(p("2.1").beats(&p("2.2.1.1")));
        assert!(p("1.2").beats(&p("1.2.1")));
        assert!(!p("1.2.1").beats(&p("1.2")));
        assert!(Priority::ROOT.beats(&p("1")));
        assert!(!p("1").beats(&p("1")));
    }

    #[test]
    fn contract_priority_display_parse_roundtrip() {
        for s in ["1", "1.2.5", "2.2.1.1", "65535.1", "root"] {
            assert_eq!(p(s).to_string(), s);
        }
        assert_eq!(p(" 1.2 ").to_string(), "1.2");
    }

    #[test]
    fn contract_priority_parse_errors() {
        assert_eq!("".parse::<Priority>(), Err(PriorityError::Empty));
        assert!(matches!(
            "1..2".parse::<Priority>(),
            Err(PriorityError::BadComponent { position: 2, .. })
        ));
        assert!(matches!(
            "1.x".parse::<Priority>(),
            Err(PriorityError::BadComponent { position: 2, .. })
        ));
        assert!(matches!(
            "1.-2".parse::<Priority>(),
            Err(PriorityError::BadComponent { .. })
        ));
        assert!(matches!(
            "70000".parse::<Priority>(),
            Err(PriorityError::BadComponent { .. })
        ));
        assert_eq!(
            "1.0".parse::<Priority>(),
            Err(PriorityError::Zero { position: 2 })
        );
        let deep = vec!["1"; MAX_DEPTH + 1].join(".");
        assert_eq!(
            deep.parse::<Priority>(),
            Err(PriorityError::TooDeep {
                depth: MAX_DEPTH + 1
            })
        );
        let msg = "1.x".parse::<Priority>().unwrap_err().to_string();
        assert!(msg.contains("\"x\"") && msg.contains("1.x"), "{msg}");
    }

    #[test]
    fn contract_priority_child_and_depth() {
        assert_eq!(Priority::objective(2).unwrap().child(1).unwrap(), p("2.1"));
        assert!(Priority::objective(0).is_err());
        let mut q = Priority::ROOT;
        for _ in 0..MAX_DEPTH {
            q = q.child(1).unwrap();
        }
        assert!(matches!(q.child(1), Err(PriorityError::TooDeep { .. })));
    }

    #[test]
    fn contract_priority_degraded_admission() {
        let min = p("2");
        assert!(p("1.5.7").admitted_by(&min));
        assert!(p("2").admitted_by(&min));
        assert!(p("2.2.1.1").admitted_by(&min));
        assert!(!p("3").admitted_by(&min));
        assert!(!p("3.1").admitted_by(&min));
        let min = p("2.1");
        assert!(p("2").admitted_by(&min));
        assert!(p("2.1.9").admitted_by(&min));
        assert!(!p("2.2").admitted_by(&min));
        assert!(p("1.9.9").admitted_by(&min));
        assert!(Priority::ROOT.admitted_by(&min));
    }

    #[test]
    fn contract_priority_most_important() {
        let v = [p("2.2.1.2"), p("1.1"), p("2.1")];
        assert_eq!(Priority::most_important(v), Some(p("1.1")));
        assert_eq!(Priority::most_important([]), None);
    }
}
