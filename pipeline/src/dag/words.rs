//! A stage's command as arguments: the `cmd` template is split into words once, as a
//! POSIX shell would split it (quotes and backslashes, via the `shlex` crate), and
//! `${...}` is then substituted inside each word. The runner executes the words
//! directly, with no shell: a value (`[vars]`, a params value, a `--set` value, a
//! `foreach` item) reaches the stage as exactly one argument, or as part of the one
//! word it was written in, whatever spaces, quotes, `$`, backticks or `;` it holds.
//!
//! Since no shell runs, shell syntax in a template (`|`, `&&`, `;`, `<`, `>`,
//! backticks, `$(...)`, `VAR=value cmd`) would be passed to the program as arguments;
//! [`split`] refuses it with the reason. A stage that needs a shell names one and hands
//! it the values as arguments: `cmd = "sh -c 'a \"$1\" && b' sh ${value}"`; a value
//! substituted *into* the script of `sh -c` would be parsed by that shell again, so it
//! is refused too.
//!
//! [`quote`] and [`join`] write arguments back as one shell-safe line (the `shlex`
//! crate's quoting): the form the lock records, logs show and the Snakemake export runs.

/// Characters that mean something to a shell outside quotes.
const OPERATORS: &[char] = &['|', '&', ';', '<', '>', '`', '(', ')'];

/// Shells whose `-c` script would parse a substituted value.
const SHELLS: &[&str] = &["sh", "bash", "dash", "zsh", "ksh", "ash", "busybox"];

/// Split a `cmd` template into words (before substitution). Errors name the problem:
/// an unterminated quote, or shell syntax that no shell will interpret.
pub fn split(template: &str) -> Result<Vec<String>, String> {
    if let Some(op) = unquoted_operator(template) {
        return Err(format!(
            "`{op}` is shell syntax, and stages run without a shell (each value reaches the \
             stage as one argument); write a script, or name the shell and pass values as \
             its arguments: cmd = \"sh -c 'a \\\"$1\\\" && b' sh ${{value}}\""
        ));
    }
    let words = shlex::split(template)
        .ok_or_else(|| "unterminated quote or trailing backslash".to_string())?;
    let Some(first) = words.first() else {
        return Err("empty command".into());
    };
    if let Some((name, _)) = first.split_once('=')
        && !name.is_empty()
        && !name.contains('/')
    {
        return Err(format!(
            "`{first}` sets an environment variable, which needs a shell; stages run without \
             one: write `env {first} ...`"
        ));
    }
    Ok(words)
}

/// Refuse `${...}` substituted into the script of `sh -c SCRIPT` (`words` as split,
/// before substitution): the shell would parse the value.
pub fn check_shell_script(words: &[String]) -> Result<(), String> {
    let prog = words
        .first()
        .map(|w| w.rsplit('/').next().unwrap_or(w))
        .unwrap_or("");
    if !SHELLS.contains(&prog) {
        return Ok(());
    }
    let mut it = words.iter().skip(1);
    while let Some(w) = it.next() {
        if w.starts_with('-') && !w.starts_with("--") && w.contains('c') {
            if let Some(script) = it.next()
                && has_substitution(script)
            {
                return Err(format!(
                    "the script of `{prog} -c` contains a `${{...}}` value, which that shell \
                     would parse as code; pass the value as an argument after the script and \
                     read it as \"$1\": cmd = \"{prog} -c '... \\\"$1\\\" ...' {prog} ${{value}}\""
                ));
            }
            break;
        }
        if !w.starts_with('-') {
            break;
        }
    }
    Ok(())
}

/// Whether `word` holds a `${...}` reference (not the literal `$${`).
fn has_substitution(word: &str) -> bool {
    let b = word.as_bytes();
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'$' {
            if b.get(i + 1) == Some(&b'$') && b.get(i + 2) == Some(&b'{') {
                i += 3;
                continue;
            }
            if b.get(i + 1) == Some(&b'{') {
                return true;
            }
        }
        i += 1;
    }
    false
}

/// The first shell operator outside quotes (and outside `${...}` references), as written.
fn unquoted_operator(s: &str) -> Option<String> {
    #[derive(PartialEq)]
    enum Q {
        None,
        Single,
        Double,
    }
    let chars: Vec<char> = s.chars().collect();
    let mut q = Q::None;
    let mut i = 0;
    let mut word_start = true;
    while i < chars.len() {
        let c = chars[i];
        match q {
            Q::Single => {
                if c == '\'' {
                    q = Q::None;
                }
            }
            Q::Double => match c {
                '\\' => i += 1,
                '"' => q = Q::None,
                '`' => return Some("`".into()),
                '$' if chars.get(i + 1) == Some(&'(') => return Some("$(".into()),
                _ => {}
            },
            Q::None => match c {
                '\\' => i += 1,
                '\'' => q = Q::Single,
                '"' => q = Q::Double,
                '#' if word_start => {
                    // A comment to the end of the line (as shlex reads it).
                    while i < chars.len() && chars[i] != '\n' {
                        i += 1;
                    }
                }
                '$' if chars.get(i + 1) == Some(&'{') => {
                    // A reference: skip to its end.
                    while i < chars.len() && chars[i] != '}' {
                        i += 1;
                    }
                }
                c if OPERATORS.contains(&c) => {
                    let mut op = c.to_string();
                    if let Some(&n) = chars.get(i + 1)
                        && OPERATORS.contains(&n)
                        && n != '`'
                    {
                        op.push(n);
                    }
                    if c == '(' && i > 0 && chars[i - 1] == '$' {
                        op = "$(".into();
                    }
                    return Some(op);
                }
                _ => {}
            },
        }
        word_start = q == Q::None && chars.get(i).is_some_and(|c| c.is_whitespace());
        i += 1;
    }
    None
}

/// One argument as a shell word (unchanged when it needs no quotes). A NUL cannot be
/// an argument at all; it is shown as `\0` (the runner refuses such a command).
pub fn quote(arg: &str) -> String {
    match shlex::try_quote(arg) {
        Ok(q) => q.into_owned(),
        Err(_) => shlex::try_quote(&arg.replace('\0', "\\0"))
            .map(|q| q.into_owned())
            .unwrap_or_default(),
    }
}

/// Arguments as one shell command line.
pub fn join<S: AsRef<str>>(argv: &[S]) -> String {
    argv.iter()
        .map(|a| quote(a.as_ref()))
        .collect::<Vec<_>>()
        .join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_like_a_shell_and_keeps_references_whole() {
        assert_eq!(
            split("a --p '${prompt}' \"x y\" z\\ w ${v}").unwrap(),
            ["a", "--p", "${prompt}", "x y", "z w", "${v}"]
        );
        assert_eq!(
            split("echo $${HOME} $$").unwrap(),
            ["echo", "$${HOME}", "$$"]
        );
        assert!(split("a 'b").unwrap_err().contains("unterminated"));
        assert!(split("   ").unwrap_err().contains("empty"));
    }

    #[test]
    fn refuses_shell_syntax_outside_quotes() {
        for (cmd, op) in [
            ("a && b", "&&"),
            ("a | b", "|"),
            ("a; b", ";"),
            ("a > f", ">"),
            ("a 2>&1", ">&"),
            ("a < f", "<"),
            ("a `b`", "`"),
            ("a $(b)", "$("),
            ("a \"$(b)\"", "$("),
            ("a \"`b`\"", "`"),
        ] {
            let e = split(cmd).unwrap_err();
            assert!(e.contains(&format!("`{op}`")), "{cmd}: {e}");
        }
        // Quoted, escaped or inside a reference: not syntax.
        for cmd in [
            "a 'x && y'",
            "a \"x | y\"",
            "a x\\;y",
            "sh -c 'a \"$1\" > f' sh ${v}",
            "a ${x}",
        ] {
            assert!(split(cmd).is_ok(), "{cmd}");
        }
        assert!(split("A=1 prog").unwrap_err().contains("env A=1"));
        assert!(split("env A=1 prog --k=v ./x=y").is_ok());
    }

    #[test]
    fn refuses_values_in_a_shell_script() {
        let w = |s: &str| split(s).unwrap();
        assert!(check_shell_script(&w("sh -c 'echo ${v}'")).is_err());
        assert!(check_shell_script(&w("/bin/bash -ec 'echo ${v}'")).is_err());
        assert!(check_shell_script(&w("sh -c 'echo \"$1\"' sh ${v}")).is_ok());
        assert!(check_shell_script(&w("sh -c 'echo $${HOME}'")).is_ok());
        assert!(check_shell_script(&w("prog -c ${v}")).is_ok());
        assert!(check_shell_script(&w("sh script.sh ${v}")).is_ok());
    }

    #[test]
    fn quoting_round_trips_through_split() {
        for argv in [
            vec![
                "a", "b c", "it's", "$HOME", "`x`", "ünï", "", "a\"b", "--k=v", "#x",
            ],
            vec!["x;y", "a&&b", "\\", "new\nline"],
        ] {
            let line = join(&argv);
            assert_eq!(shlex::split(&line).unwrap(), argv, "{line}");
        }
        assert_eq!(
            join(&["render-views", "--out", "runs/v"]),
            "render-views --out runs/v"
        );
    }
}
