//! Validation on the shared real data sets (skipped with a reason if absent).

use std::path::PathBuf;

/// `<workspace>/../shared/data/<rel>`, or `None` (with a printed skip reason) if missing.
fn shared(rel: &str) -> Option<PathBuf> {
    let ws = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let p = ws.join("../shared/data").join(rel);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("SKIP: {} not found", p.display());
        None
    }
}

/// `<workspace>/tests/data/<rel>`: test data kept in the repository (never skipped).
fn repo_data(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data")
        .join(rel)
}

#[test]
fn movingai_arena_every_optimal_length_exact() {
    let map = repo_data("movingai/arena.map");
    let scen = repo_data("movingai/arena.map.scen");
    let eval = hng_modules::planning::eval_movingai(&map, &scen).expect("eval");
    println!("arena: {eval:?}");
    assert_eq!(eval.problems, 160);
    assert_eq!(eval.mismatches, 0, "{eval:?}");
    assert!(eval.max_abs_err < 1e-4, "{eval:?}");
}

#[test]
fn slam_on_intel_log_meets_accuracy_aim() {
    let Some(log) = shared("carmen/intel-corrected.log") else {
        return;
    };
    let out = std::env::temp_dir().join(format!("hng-intel-map-{}", std::process::id()));
    let eval = hng_modules::slam::eval_slam(&log, Some(&out)).expect("eval");
    println!("intel: {eval:#?}");
    println!("map written to {}.pgm/.yaml", out.display());
    assert_eq!(eval.scans, 910);
    assert!(eval.trans_err_mean_m < 0.05, "{eval:?}");
    assert!(eval.rot_err_mean_deg < 1.0, "{eval:?}");
    assert!(out.with_extension("pgm").exists());
    std::fs::remove_file(out.with_extension("pgm")).ok();
    std::fs::remove_file(out.with_extension("yaml")).ok();
}
