//! The tissue library on the host: the TOML file the firmware compiles in
//! (`src/model/tissues.toml`), or another one like it (`--params FILE`).

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use needle_holder::model::params::{self, TissueParams, NUMBER_KEYS};

/// One library entry.
#[derive(Debug, Clone, PartialEq)]
pub struct Tissue {
    pub name: String,
    pub source: Option<String>,
    pub params: TissueParams,
}

/// The library compiled into the core (and the firmware).
pub fn builtin() -> Vec<Tissue> {
    params::LIBRARY
        .iter()
        .map(|(name, params)| Tissue {
            name: (*name).to_owned(),
            source: None,
            params: *params,
        })
        .collect()
}

/// Read and check a library file. Errors name the file, the line and the
/// entry; invalid values name the field.
pub fn load(path: &Path) -> Result<Vec<Tissue>> {
    let text = crate::input::read_small_text(path)?;
    parse(&text, path)
}

/// Parse and check library text; `path` names it in errors.
pub fn parse(text: &str, path: &Path) -> Result<Vec<Tissue>> {
    let shown = path.display();
    let table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
        let line = e.span().map(|s| line_of(text, s.start)).unwrap_or(0);
        anyhow!("{shown}:{line}: {}", e.message())
    })?;
    let mut tissues = Vec::new();
    for (name, entry) in table {
        let toml::Value::Table(mut entry) = entry else {
            bail!(
                "{shown}:{}: `{name}` is not a [table]",
                key_line(text, None, &name)
            );
        };
        let source = match entry.remove("source") {
            Some(toml::Value::String(s)) => Some(s),
            Some(_) => bail!(
                "{shown}:{}: [{name}] source must be a string",
                key_line(text, Some(&name), "source")
            ),
            None => None,
        };
        // Each known value's type first, so that an error names its key
        // and line (the deserialiser names neither for a string in place
        // of a number); an unknown key is the deserialiser's to name.
        for (key, value) in &entry {
            let number = matches!(value, toml::Value::Float(_) | toml::Value::Integer(_));
            let (ok, wanted) = match key.as_str() {
                "stiffness_law" => (value.is_str(), "a string"),
                k if NUMBER_KEYS.contains(&k) => (number, "a number"),
                _ => continue,
            };
            if !ok {
                bail!(
                    "{shown}:{}: [{name}] `{key}` must be {wanted}, not {}",
                    key_line(text, Some(&name), key),
                    value.type_str()
                );
            }
        }
        let params: TissueParams =
            toml::Value::Table(entry)
                .try_into()
                .map_err(|e: toml::de::Error| {
                    // An unknown key is named at its own line.
                    let line = unknown_field(e.message()).map_or_else(
                        || section_line(text, &name),
                        |k| key_line(text, Some(&name), k),
                    );
                    anyhow!("{shown}:{line}: [{name}] {}", e.message())
                })?;
        // The device's own check too, in its fixed point: one validation.
        needle_holder::config::TissueModel::validated(&params).map_err(|e| {
            anyhow!(
                "{shown}:{}: [{name}] {e}",
                key_line(text, Some(&name), e.field)
            )
        })?;
        tissues.push(Tissue {
            name,
            source,
            params,
        });
    }
    if tissues.is_empty() {
        bail!("{shown}: no tissue entries");
    }
    Ok(tissues)
}

/// The tissue to use: `name` from `file` when given (the first entry if no
/// name), else `name` from the built-in library (default `liver1`).
pub fn resolve(name: Option<&str>, file: Option<&Path>) -> Result<Tissue> {
    let (library, from) = match file {
        Some(path) => (load(path)?, path.display().to_string()),
        None => (builtin(), "the built-in library".to_owned()),
    };
    let wanted = name.or(file.is_none().then_some("liver1"));
    match wanted {
        None => Ok(library[0].clone()),
        Some(n) => named(&library, n, &from),
    }
}

/// The entry `name` of `library` (read from `from`), or an error listing
/// the names it has.
pub fn named(library: &[Tissue], name: &str, from: &str) -> Result<Tissue> {
    library
        .iter()
        .find(|t| t.name == name)
        .cloned()
        .ok_or_else(|| anyhow!("no tissue `{name}` in {from} (it has: {})", names(library)))
}

/// The entries' names, comma-separated.
pub fn names(library: &[Tissue]) -> String {
    let names: Vec<&str> = library.iter().map(|t| t.name.as_str()).collect();
    names.join(", ")
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

fn section_line(text: &str, name: &str) -> usize {
    let header = format!("[{name}]");
    text.lines()
        .position(|l| l.trim() == header)
        .map_or(0, |i| i + 1)
}

/// The key a deserialiser's "unknown field `key`, expected …" names.
fn unknown_field(message: &str) -> Option<&str> {
    let rest = message.strip_prefix("unknown field `")?;
    rest.split('`').next()
}

/// Line of `key = …` (or of a `[name.key]` table) inside section `name`
/// (or at top level), else the section's own line.
fn key_line(text: &str, section: Option<&str>, key: &str) -> usize {
    // `start` is the header's 1-based line, so skipping it starts below it.
    let start = section.map_or(0, |s| section_line(text, s));
    if let Some(s) = section {
        let header = format!("[{s}.{key}]");
        if let Some(i) = text.lines().position(|l| l.trim() == header) {
            return i + 1;
        }
    }
    for (i, line) in text.lines().enumerate().skip(start) {
        if line.trim_start().starts_with('[') {
            break;
        }
        if line.split('=').next().is_some_and(|k| k.trim() == key) {
            return i + 1;
        }
    }
    start
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_the_firmware_compiles_in_loads_to_the_same_values() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../src/model/tissues.toml");
        let loaded = load(&path).unwrap();
        let builtin = builtin();
        assert_eq!(loaded.len(), builtin.len());
        for (a, b) in loaded.iter().zip(&builtin) {
            assert_eq!((&a.name, a.params), (&b.name, b.params));
            assert!(a.source.is_some());
        }
    }

    #[test]
    fn bad_files_name_file_line_entry_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let good = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../src/model/tissues.toml"),
        )
        .unwrap();
        let cases = [
            (
                good.replacen("dp_n_per_m = 30.4", "dp_n_per_m = -30.4", 1),
                "[liver1] `dp_n_per_m` is negative",
            ),
            (
                good.replacen("half_band_mps = 5.0e-6", "half_band_mps = 0.0", 1),
                "`half_band_mps` must be positive",
            ),
            (
                good.replacen("a2_n_per_m2 = 5200.0", "a2_n_per_m2 = nan", 1),
                "`a2_n_per_m2` is not a finite",
            ),
            (
                good.replacen("cutting_force_n = 0.94", "cutting_forse_n = 0.94", 1),
                "unknown field `cutting_forse_n`",
            ),
            (
                good.replacen("relaxation = 0.5", "relaxation = \"half\"", 1),
                "[liver1]",
            ),
            ("[liver1\n".to_owned(), "t.toml:1:"),
            // Detector figures that contradict each other.
            (
                good.replacen(
                    "puncture_drop_to_n = 0.6579",
                    "puncture_drop_to_n = -0.2",
                    1,
                ),
                "[liver1] `puncture_drop_to_n` is negative",
            ),
            (
                good.replacen(
                    "puncture_force_sd_n = 0.83",
                    "puncture_force_sd_n = -0.83",
                    1,
                ),
                "[liver1] `puncture_force_sd_n` is negative",
            ),
            (
                good.replacen(
                    "puncture_force_sd_n = 0.83",
                    "puncture_force_sd_n = 0.83\npuncture_drop_sd_n = -0.1",
                    1,
                ),
                "[liver1] `puncture_drop_sd_n` is negative",
            ),
        ];
        for (text, expected) in cases {
            let path = dir.path().join("t.toml");
            std::fs::write(&path, &text).unwrap();
            let err = format!("{:#}", load(&path).unwrap_err());
            assert!(
                err.contains("t.toml") && err.contains(expected),
                "{err} lacks {expected}"
            );
        }
        // An unknown key, a nested table and bytes that are no text are
        // named at their own line.
        let unknown = good.replacen("relaxation = 0.5", "relaxation = 0.5\nbogus_key = 1.0", 1);
        let nested = format!("{good}\n[liver1.extra]\nx = 1\n");
        let mut binary = good.clone().into_bytes();
        binary.splice(0..0, *b"# \xff\n");
        for (bytes, line_of) in [
            (unknown.clone().into_bytes(), "bogus_key = 1.0"),
            (nested.clone().into_bytes(), "[liver1.extra]"),
        ] {
            let text = String::from_utf8(bytes.clone()).unwrap();
            let line = text.lines().position(|l| l == line_of).unwrap() + 1;
            std::fs::write(dir.path().join("t.toml"), &bytes).unwrap();
            let err = format!("{:#}", load(&dir.path().join("t.toml")).unwrap_err());
            assert!(
                err.contains(&format!("t.toml:{line}:")),
                "{err} lacks line {line}"
            );
        }
        std::fs::write(dir.path().join("t.toml"), &binary).unwrap();
        let err = format!("{:#}", load(&dir.path().join("t.toml")).unwrap_err());
        assert!(
            err.contains("t.toml:1: not UTF-8 text (byte 0xff at column 3)"),
            "{err}"
        );
        // The line points at the offending key.
        let text = good.replacen("dp_n_per_m = 30.4", "dp_n_per_m = -30.4", 1);
        let line = text
            .lines()
            .position(|l| l.starts_with("dp_n_per_m = -30.4"))
            .unwrap()
            + 1;
        std::fs::write(dir.path().join("t.toml"), &text).unwrap();
        let err = format!("{:#}", load(&dir.path().join("t.toml")).unwrap_err());
        assert!(err.contains(&format!("t.toml:{line}:")), "{err}");
    }

    #[test]
    fn resolve_finds_by_name_and_lists_the_names_when_it_cannot() {
        assert_eq!(resolve(None, None).unwrap().name, "liver1");
        assert_eq!(
            resolve(Some("liver2"), None).unwrap().params.a1_n_per_m,
            2.0
        );
        let err = resolve(Some("spleen"), None).unwrap_err().to_string();
        assert!(err.contains("liver1_journal"), "{err}");
    }
}
