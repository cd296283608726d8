//! How a parameter struct is declared once: clap is its schema. Each field's doc comment
//! is its help text, its `#[arg(default_value...)]` its default; serde reads and writes
//! the same struct from TOML (configuration files, a DAG's params tables) and into
//! artifact manifests. One declaration serves the command line, the files and the docs:
//!
//! * [`defaults`]: a struct with every field at its declared default (what `Default`
//!   returns for these structs, and what serde fills a missing key with);
//! * [`typed_value`]: one `KEY=VALUE` of the command line (`--set`) parsed by the key's
//!   own parser (its type, its possible values) into the TOML value a file would hold;
//! * [`key_help`]: the keys, their defaults and their docs, for a `--help` page.

use crate::{Error, Result};

/// `T` with every field at the default its clap declaration gives.
pub fn defaults<T: clap::Args + clap::FromArgMatches>() -> T {
    let cmd = T::augment_args(clap::Command::new("defaults").no_binary_name(true));
    let m = cmd
        .try_get_matches_from(std::iter::empty::<String>())
        .expect("every field of a parameter struct has a default");
    T::from_arg_matches(&m).expect("the defaults parse")
}

/// The TOML value of field `key` of `T` given as `value` on the command line: parsed by
/// the field's clap parser (so `--set` accepts and refuses exactly what a flag would),
/// then written as serde writes the field. `section` names `T`'s keys in messages
/// (e.g. `csd.`; empty at the top level).
pub fn typed_value<T>(section: &str, key: &str, value: &str) -> Result<toml::Value>
where
    T: clap::Args + clap::FromArgMatches + serde::Serialize,
{
    let cmd = T::augment_args(clap::Command::new("set").no_binary_name(true));
    let Some(arg) = cmd.get_arguments().find(|a| a.get_id() == key) else {
        return Err(Error::param(format!(
            "unknown configuration key `{section}{key}`; the keys of {}: {}",
            if section.is_empty() {
                "the top level".to_string()
            } else {
                format!("[{}]", section.trim_end_matches('.'))
            },
            keys::<T>().join(", ")
        )));
    };
    let long = arg.get_long().expect("parameter fields are long flags");
    let m = cmd
        .clone()
        .try_get_matches_from([format!("--{long}"), value.to_string()])
        .map_err(|e| {
            let msg = e.render().to_string();
            let first = msg
                .lines()
                .next()
                .unwrap_or("")
                .trim_start_matches("error: ");
            Error::param(format!("{section}{key}={value}: {first}"))
        })?;
    let t = T::from_arg_matches(&m).map_err(|e| Error::param(e.to_string()))?;
    let table = toml::Table::try_from(&t).map_err(|e| Error::Other(e.to_string()))?;
    table
        .get(key)
        .cloned()
        .ok_or_else(|| Error::param(format!("{section}{key}: no value")))
}

/// The keys (field names) of `T`.
pub fn keys<T: clap::Args>() -> Vec<String> {
    T::augment_args(clap::Command::new("keys"))
        .get_arguments()
        .map(|a| a.get_id().to_string())
        .collect()
}

/// `T`'s keys for a help page: `  KEY [default: D] [values: ...]` and the doc comment
/// below it, indented; `section` prefixes each key (e.g. `csd.`).
pub fn key_help<T: clap::Args>(section: &str) -> String {
    let cmd = T::augment_args(clap::Command::new("help"));
    let mut out = String::new();
    for a in cmd.get_arguments() {
        let mut line = format!("  {section}{}", a.get_id());
        let defaults: Vec<String> = a
            .get_default_values()
            .iter()
            .map(|v| v.to_string_lossy().into_owned())
            .collect();
        if !defaults.is_empty() {
            line += &format!(" [default: {}]", defaults.join(","));
        }
        let values: Vec<String> = a
            .get_possible_values()
            .iter()
            .filter(|v| !v.is_hide_set())
            .map(|v| v.get_name().to_string())
            .collect();
        if !values.is_empty() && values != ["true", "false"] {
            line += &format!(" [values: {}]", values.join(", "));
        }
        out += &line;
        out.push('\n');
        let doc = a
            .get_long_help()
            .or(a.get_help())
            .map(|h| h.to_string())
            .unwrap_or_default();
        for l in textwrap(&doc, 84) {
            out += &format!("          {l}\n");
        }
    }
    out
}

/// `text` re-wrapped at `width` columns (paragraphs kept).
fn textwrap(text: &str, width: usize) -> Vec<String> {
    let mut lines = Vec::new();
    for para in text.split("\n\n") {
        let mut line = String::new();
        for word in para.split_whitespace() {
            if !line.is_empty() && line.len() + 1 + word.len() > width {
                lines.push(std::mem::take(&mut line));
            }
            if !line.is_empty() {
                line.push(' ');
            }
            line += word;
        }
        if !line.is_empty() {
            lines.push(line);
        }
    }
    lines
}

/// Serialize and deserialize a [`clap::ValueEnum`] by its command-line name, so that a
/// file and a flag spell every value the same way.
macro_rules! serde_by_value_name {
    ($($t:ty),* $(,)?) => {$(
        impl serde::Serialize for $t {
            fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
                let v = clap::ValueEnum::to_possible_value(self).expect("no skipped value");
                s.serialize_str(v.get_name())
            }
        }
        impl<'de> serde::Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
                let s = <String as serde::Deserialize>::deserialize(d)?;
                <$t as clap::ValueEnum>::from_str(&s, false).map_err(|_| {
                    let names: Vec<String> = <$t as clap::ValueEnum>::value_variants()
                        .iter()
                        .filter_map(|v| clap::ValueEnum::to_possible_value(v))
                        .map(|v| v.get_name().to_string())
                        .collect();
                    serde::de::Error::custom(format!(
                        "`{s}` is not one of {}",
                        names.join(", ")
                    ))
                })
            }
        }
    )*};
}

pub(crate) use serde_by_value_name;

#[cfg(test)]
mod tests {
    use super::*;

    /// A parameter struct as the crate declares them.
    #[derive(clap::Args, serde::Serialize, serde::Deserialize, Debug, PartialEq)]
    struct P {
        /// A count.
        #[arg(long, default_value_t = 4)]
        views: usize,
        /// A switch.
        #[arg(long, default_value_t = false, action = clap::ArgAction::Set)]
        fit_rest: bool,
    }

    #[test]
    fn defaults_and_typed_values_come_from_the_declaration() {
        let p: P = defaults();
        assert_eq!(
            p,
            P {
                views: 4,
                fit_rest: false
            }
        );
        assert_eq!(
            typed_value::<P>("", "views", "7").unwrap(),
            toml::Value::Integer(7)
        );
        assert_eq!(
            typed_value::<P>("", "fit_rest", "true").unwrap(),
            toml::Value::Boolean(true)
        );
        let e = typed_value::<P>("", "views", "many")
            .unwrap_err()
            .to_string();
        assert!(e.contains("views=many"), "{e}");
        let e = typed_value::<P>("s.", "view", "1").unwrap_err().to_string();
        assert!(
            e.contains("`s.view`") && e.contains("views, fit_rest"),
            "{e}"
        );
        let h = key_help::<P>("s.");
        assert!(
            h.contains("s.views [default: 4]") && h.contains("A count"),
            "{h}"
        );
    }
}
