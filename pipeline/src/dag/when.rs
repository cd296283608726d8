//! A stage's `when`: the condition, after `${...}` substitution, under which the stage
//! exists at all (`when = "${distill.chunks} > 0"`: the loop's stages appear only when a
//! loop is configured). A stage whose condition fails is no stage: nothing runs it,
//! nothing may depend on it, and its outputs may be another stage's (the one whose
//! condition holds).
//!
//! The condition is one value (true unless it is empty, `false` or a number equal to
//! 0) or two values around one of `==`, `!=`, `>=`, `<=`, `>`, `<`: numbers compare as
//! numbers, other values as text (`==` and `!=` only).

/// Whether condition `text` holds, or why it cannot be read.
pub(super) fn holds(text: &str) -> Result<bool, String> {
    for op in ["==", "!=", ">=", "<=", ">", "<"] {
        if let Some((a, b)) = text.split_once(op) {
            return compare(a.trim(), op, b.trim());
        }
    }
    let v = text.trim();
    Ok(match v.parse::<f64>() {
        Ok(x) => x != 0.0,
        Err(_) => !(v.is_empty() || v == "false"),
    })
}

fn compare(a: &str, op: &str, b: &str) -> Result<bool, String> {
    if a.is_empty() || b.is_empty() {
        return Err(format!("`{op}` needs a value on each side"));
    }
    match (a.parse::<f64>(), b.parse::<f64>()) {
        (Ok(x), Ok(y)) => Ok(match op {
            "==" => x == y,
            "!=" => x != y,
            ">=" => x >= y,
            "<=" => x <= y,
            ">" => x > y,
            _ => x < y,
        }),
        _ => match op {
            "==" => Ok(a == b),
            "!=" => Ok(a != b),
            _ => Err(format!(
                "`{op}` compares numbers; `{a}` and `{b}` are not both numbers"
            )),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::holds;

    #[test]
    fn values_and_comparisons() {
        assert_eq!(holds("0"), Ok(false));
        assert_eq!(holds(" 2 "), Ok(true));
        assert_eq!(holds("0.0"), Ok(false));
        assert_eq!(holds(""), Ok(false));
        assert_eq!(holds("false"), Ok(false));
        assert_eq!(holds("true"), Ok(true));
        assert_eq!(holds("2 > 0"), Ok(true));
        assert_eq!(holds("0 > 0"), Ok(false));
        assert_eq!(holds("0 == 0.0"), Ok(true));
        assert_eq!(holds("1 >= 2"), Ok(false));
        assert_eq!(holds("3 <= 3"), Ok(true));
        assert_eq!(holds("-1 < 0"), Ok(true));
        assert_eq!(holds("arf != default"), Ok(true));
        assert_eq!(holds("arf == arf"), Ok(true));
        assert!(holds("arf > 0").unwrap_err().contains("numbers"));
        assert!(holds("> 0").unwrap_err().contains("each side"));
    }
}
