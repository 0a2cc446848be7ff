//! The workspace's crates depend one way, as `cargo metadata` reads them:
//! the wire format at the bottom on no crate of the workspace, the core on
//! the wire format and the driver, the host's libraries above the core,
//! and nothing below depending on anything above.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// Each workspace package's name and the workspace packages it depends on
/// (any kind: normal, build, dev).
fn workspace_dependencies() -> BTreeMap<String, Vec<String>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = Command::new(env!("CARGO"))
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--offline",
        ])
        .current_dir(&root)
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let metadata: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let packages = metadata["packages"].as_array().unwrap();
    let names: Vec<&str> = packages
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    packages
        .iter()
        .map(|p| {
            let deps = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .map(|d| d["name"].as_str().unwrap())
                .filter(|d| names.contains(d))
                .map(String::from)
                .collect();
            (p["name"].as_str().unwrap().to_string(), deps)
        })
        .collect()
}

#[test]
fn the_wire_format_depends_on_no_crate_of_the_workspace_and_nothing_depends_upward() {
    let deps = workspace_dependencies();
    assert_eq!(deps["needle-wire"], Vec::<String>::new(), "{deps:?}");
    assert_eq!(deps["ads1220"], Vec::<String>::new(), "{deps:?}");
    // From the bottom up; each may depend only on crates before it (the
    // one exception, in tests only: needle-io's tests simulate an
    // insertion with needle-analysis, written in its Cargo.toml).
    let order = [
        "needle-wire",
        "ads1220",
        "needle-holder",
        "needle-holder-firmware",
        "needle-io",
        "needle-analysis",
        "needle-qemu",
        "needle-live",
        "xtask",
        "host-tools",
    ];
    assert_eq!(
        deps.keys()
            .map(String::as_str)
            .collect::<std::collections::BTreeSet<_>>(),
        order.iter().copied().collect(),
        "every crate of the workspace has its place in the order"
    );
    for (at, name) in order.iter().enumerate() {
        for dep in &deps[*name] {
            let below = order[..at].contains(&dep.as_str());
            let test_cycle = *name == "needle-io" && dep == "needle-analysis";
            assert!(below || test_cycle, "{name} depends on {dep}, above it");
        }
    }
}
