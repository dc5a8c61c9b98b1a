//! Loops the composer unrolls. A `for` loop on the line after a `// unroll` comment, of the form
//! `for (var x = A; x < B; x++) {` with A and B constant (integer literals, the module's integer
//! constants such as `DIM`, the values of enclosing unrolled loops, and `+ - * /` on them),
//! becomes one block per value of `x`, with `x` replaced by that value. The indices computed
//! from it are then constants, and an array indexed by them stays in registers: drivers do not
//! always unroll a loop themselves, and an array they must index at run time goes to memory
//! (on lavapipe, the Tri3 tangent kernel took twice as long with its pair tensor's loops left
//! to the driver, and the Hex8 F-bar kernel three times as long with its pair blocks' loops;
//! doc/benchmarks.md, "Constant indices in
//! the pair tensor and the F-bar pair blocks").

use std::collections::HashMap;

const MARKER: &str = "// unroll";

/// `module` with its marked loops unrolled.
pub fn unroll(module: &str) -> Result<String, String> {
    if !module.contains(MARKER) {
        return Ok(module.to_string());
    }
    expand(module, &constants(module))
}

/// The module's `const NAME = <integer expression>;` definitions that evaluate.
fn constants(module: &str) -> HashMap<String, i64> {
    let mut known = HashMap::new();
    for line in module.lines() {
        let Some(rest) = line.trim().strip_prefix("const ") else { continue };
        let Some((name, value)) = rest.split_once('=') else { continue };
        let (name, value) = (name.trim(), value.trim().trim_end_matches(';'));
        if let Ok(v) = evaluate(value, &known) {
            known.insert(name.to_string(), v);
        }
    }
    known
}

fn expand(text: &str, known: &HashMap<String, i64>) -> Result<String, String> {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find(MARKER) {
        out.push_str(&rest[..at]);
        let after = &rest[at + MARKER.len()..];
        let header_start = after.find('\n').ok_or("`// unroll` at the end of the module")? + 1;
        let header_end = after[header_start..].find('{').ok_or("`// unroll` before no loop")? + header_start;
        let (name, first, end) = loop_header(&after[header_start..header_end], known)?;
        let close = matching_brace(after, header_end)?;
        let body = &after[header_end + 1..close];
        if contains_word(body, "break") || contains_word(body, "continue") {
            return Err(format!("an unrolled loop over `{name}` breaks or continues"));
        }
        for value in first..end {
            out.push_str("{\n");
            out.push_str(&expand(&substitute(body, &name, &format!("{value}u")), known)?);
            out.push_str("}\n");
        }
        rest = &after[close + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// `for (var x = A; x < B; x++)`: the variable and its constant range.
fn loop_header(header: &str, known: &HashMap<String, i64>) -> Result<(String, i64, i64), String> {
    let bad = || format!("not a loop the composer unrolls: `{}`", header.trim());
    let inner = header.trim().strip_prefix("for").map(str::trim).and_then(|s| s.strip_prefix('(')).and_then(|s| s.strip_suffix(')')).ok_or_else(bad)?;
    let parts: Vec<&str> = inner.split(';').map(str::trim).collect();
    let [init, test, step] = parts[..] else { return Err(bad()) };
    let (name, first) = init.strip_prefix("var ").and_then(|s| s.split_once('=')).ok_or_else(bad)?;
    let name = name.trim();
    let (tested, end) = test.split_once('<').ok_or_else(bad)?;
    if tested.trim() != name || end.starts_with('=') || step != format!("{name}++") {
        return Err(bad());
    }
    Ok((name.to_string(), evaluate(first.trim(), known)?, evaluate(end.trim(), known)?))
}

/// The index of the `}` that closes the `{` at `open`.
fn matching_brace(text: &str, open: usize) -> Result<usize, String> {
    let mut depth = 0;
    let mut in_comment = false;
    let bytes = text.as_bytes();
    for (i, &b) in bytes.iter().enumerate().skip(open) {
        match b {
            b'\n' => in_comment = false,
            b'/' if !in_comment && bytes.get(i + 1) == Some(&b'/') => in_comment = true,
            b'{' if !in_comment => depth += 1,
            b'}' if !in_comment => {
                depth -= 1;
                if depth == 0 {
                    return Ok(i);
                }
            }
            _ => {}
        }
    }
    Err("an unrolled loop without its closing brace".into())
}

fn is_identifier(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b == b'_'
}

/// Where the identifier `word` stands in `text` as a name of its own (not part of another, not
/// a member after a `.`).
fn word_positions<'a>(text: &'a str, word: &'a str) -> impl Iterator<Item = usize> + 'a {
    let bytes = text.as_bytes();
    text.match_indices(word).map(|(i, _)| i).filter(move |&i| {
        let before = i.checked_sub(1).map(|j| bytes[j]);
        let after = bytes.get(i + word.len()).copied();
        !before.is_some_and(|b| is_identifier(b) || b == b'.') && !after.is_some_and(is_identifier)
    })
}

fn contains_word(text: &str, word: &str) -> bool {
    word_positions(text, word).next().is_some()
}

fn substitute(text: &str, word: &str, value: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut last = 0;
    for i in word_positions(text, word) {
        out.push_str(&text[last..i]);
        out.push_str(value);
        last = i + word.len();
    }
    out.push_str(&text[last..]);
    out
}

/// An integer expression of literals (`3`, `3u`), known constants, `+ - * /` and parentheses.
fn evaluate(expression: &str, known: &HashMap<String, i64>) -> Result<i64, String> {
    let tokens = tokens(expression)?;
    let mut at = 0;
    let value = sum(&tokens, &mut at, known)?;
    if at != tokens.len() {
        return Err(format!("not a constant integer: `{expression}`"));
    }
    Ok(value)
}

fn tokens(expression: &str) -> Result<Vec<String>, String> {
    let mut out = Vec::new();
    let mut chars = expression.chars().peekable();
    while let Some(&c) = chars.peek() {
        if c.is_whitespace() {
            chars.next();
        } else if "+-*/()".contains(c) {
            out.push(c.to_string());
            chars.next();
        } else if c.is_ascii_alphanumeric() || c == '_' {
            let mut word = String::new();
            while let Some(&c) = chars.peek().filter(|c| c.is_ascii_alphanumeric() || **c == '_') {
                word.push(c);
                chars.next();
            }
            out.push(word);
        } else {
            return Err(format!("not a constant integer: `{expression}`"));
        }
    }
    Ok(out)
}

fn sum(tokens: &[String], at: &mut usize, known: &HashMap<String, i64>) -> Result<i64, String> {
    let mut value = product(tokens, at, known)?;
    while let Some(op) = tokens.get(*at).filter(|t| *t == "+" || *t == "-").cloned() {
        *at += 1;
        let rhs = product(tokens, at, known)?;
        value = if op == "+" { value + rhs } else { value - rhs };
    }
    Ok(value)
}

fn product(tokens: &[String], at: &mut usize, known: &HashMap<String, i64>) -> Result<i64, String> {
    let mut value = atom(tokens, at, known)?;
    while let Some(op) = tokens.get(*at).filter(|t| *t == "*" || *t == "/").cloned() {
        *at += 1;
        let rhs = atom(tokens, at, known)?;
        value = if op == "*" { value * rhs } else { value.checked_div(rhs).ok_or("a division by zero")? };
    }
    Ok(value)
}

fn atom(tokens: &[String], at: &mut usize, known: &HashMap<String, i64>) -> Result<i64, String> {
    let token = tokens.get(*at).ok_or("an incomplete constant expression")?;
    *at += 1;
    if token == "(" {
        let value = sum(tokens, at, known)?;
        if tokens.get(*at).map(String::as_str) != Some(")") {
            return Err("an unclosed parenthesis".into());
        }
        *at += 1;
        return Ok(value);
    }
    if let Some(&v) = known.get(token) {
        return Ok(v);
    }
    token.trim_end_matches(['u', 'i']).parse().map_err(|_| format!("`{token}` is not a known integer constant"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_marked_loop_becomes_one_block_per_value_with_its_variable_replaced() {
        let module = "const DIM = 2u;\nfn f() {\n    // unroll\n    for (var row = 0u; row < DIM * DIM; row++) {\n        // unroll\n        for (var col = row; col < DIM * DIM; col++) {\n            a[row * 4u + col] = x.row + rows;\n        }\n    }\n    for (var k = 0u; k < 3u; k++) { b[k] = 1.0; }\n}\n";
        let out = unroll(module).unwrap();
        // 4 + 3 + 2 + 1 inner blocks, each assignment with its constants; `x.row` and `rows`
        // are not the variable; the unmarked loop stays.
        let assignments: Vec<&str> = out.lines().map(str::trim).filter(|l| l.starts_with("a[")).collect();
        assert_eq!(assignments.len(), 10);
        assert_eq!(assignments[0], "a[0u * 4u + 0u] = x.row + rows;");
        assert_eq!(assignments[9], "a[3u * 4u + 3u] = x.row + rows;");
        assert!(out.contains("for (var k = 0u; k < 3u; k++) { b[k] = 1.0; }"));
        assert!(!out.contains(MARKER));
        assert_eq!(unroll("fn g() {}\n").unwrap(), "fn g() {}\n");
    }

    #[test]
    fn what_cannot_be_unrolled_is_an_error_not_a_wrong_module() {
        let wrong = |header: &str, body: &str| unroll(&format!("fn f() {{\n// unroll\n{header} {{ {body} }}\n}}\n")).unwrap_err();
        assert!(wrong("for (var i = 0u; i < n; i++)", "").contains("`n` is not a known integer constant"));
        assert!(wrong("for (var i = 0u; i <= 3u; i++)", "").contains("not a loop"));
        assert!(wrong("for (var i = 0u; i < 3u; i += 2u)", "").contains("not a loop"));
        assert!(wrong("for (var i = 0u; i < 3u; i++)", "if i == 1u { break; }").contains("breaks or continues"));
        assert!(wrong("while (true)", "").contains("not a loop"));
    }

    #[test]
    fn constants_are_read_from_the_module_and_may_build_on_each_other() {
        let known = constants("const NEN = 4u;\nconst DIM = 3u;\nconst NDOF = NEN * DIM;\nconst PACKED = NDOF * (NDOF + 1u) / 2u;\nconst X = 1.5;\n");
        assert_eq!((known["NDOF"], known["PACKED"]), (12, 78));
        assert!(!known.contains_key("X"));
    }
}
