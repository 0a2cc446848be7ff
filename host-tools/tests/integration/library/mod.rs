//! The tissue library as the tests read it, from the file the firmware
//! compiles in.

/// The library's first entry (`[liver1]`) as the text of a tissue file.
pub fn liver1_entry() -> String {
    let library = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../src/model/tissues.toml"
    ))
    .unwrap();
    library
        .split("\n[")
        .nth(1)
        .map(|e| format!("[{e}"))
        .unwrap()
}
