//! The `hng` package: the command-line tool, and the benchmark drivers shared by
//! `hng bench` and the criterion benches in `benches/`.

pub mod bench;
pub mod contract_probe;
