//! Reading modules of CUDA C++ programs: what every backend that compiles them needs before
//! its compiler runs (the CUDA backend with NVRTC, the CPU backend with the host's compiler).

/// The guide's types and constants that programs name (`OptixTraversableHandle`, ray flags, hit
/// kinds, exception codes, payload, transform and primitive types, `OptixStaticTransform`), the
/// part both device headers share: each backend's compiler puts it before its device header.
#[doc(alias = "OptixTraversableHandle")]
#[doc(alias = "OptixStaticTransform")]
pub const OPTIX_TYPES_HEADER: &str = include_str!("optix_types.h");

/// The entry-name prefixes of the eight program kinds (guide §6.2).
pub const ENTRY_PREFIXES: [&str; 8] = [
    "__raygen__",
    "__intersection__",
    "__anyhit__",
    "__closesthit__",
    "__miss__",
    "__exception__",
    "__direct_callable__",
    "__continuation_callable__",
];

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Comments and string literals blanked out (same length, newlines kept), so that names in
/// them are not taken for code.
fn code_only(source: &str) -> String {
    let b = source.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let blank = |out: &mut Vec<u8>, c: u8| out.push(if c == b'\n' { b'\n' } else { b' ' });
        if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                blank(&mut out, b[i]);
                i += 1;
            }
        } else if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
            let end = source[i + 2..]
                .find("*/")
                .map_or(b.len(), |e| i + 2 + e + 2);
            while i < end {
                blank(&mut out, b[i]);
                i += 1;
            }
        } else if b[i] == b'"' || b[i] == b'\'' {
            let q = b[i];
            out.push(q);
            i += 1;
            while i < b.len() && b[i] != q && b[i] != b'\n' {
                if b[i] == b'\\' && i + 1 < b.len() {
                    blank(&mut out, b[i]);
                    i += 1;
                }
                blank(&mut out, b[i]);
                i += 1;
            }
            if i < b.len() {
                out.push(b[i]);
                i += 1;
            }
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    // Only ASCII bytes were replaced by ASCII bytes, and whole multi-byte characters by spaces
    // (their bytes are never quotes, slashes or newlines).
    String::from_utf8(out).unwrap_or_default()
}

/// Whether `source` declares or defines a function `name` (the name as a whole word, followed
/// by `(`), outside comments and strings.
#[must_use]
pub fn has_entry(source: &str, name: &str) -> bool {
    let code = code_only(source);
    let found = find_word_calls(&code, name).next().is_some();
    found
}

fn find_word_calls<'a>(code: &'a str, name: &'a str) -> impl Iterator<Item = usize> + 'a {
    code.match_indices(name).filter_map(move |(i, _)| {
        let before = code[..i].chars().next_back();
        let after = code[i + name.len()..].trim_start().chars().next();
        (!before.is_some_and(is_ident) && after == Some('(')).then_some(i)
    })
}

/// The entry points a module declares or defines: every name that starts with one of
/// [`ENTRY_PREFIXES`] and is followed by `(`, once each, in order of appearance.
///
/// ```
/// let src = "extern \"C\" __global__ void __raygen__main() {}\n// __miss__not_code()\n";
/// assert_eq!(oxray_core::source::entries(src), ["__raygen__main"]);
/// ```
pub fn entries(source: &str) -> Vec<String> {
    let code = code_only(source);
    let mut found: Vec<String> = Vec::new();
    let mut i = 0;
    while let Some(off) = code[i..].find("__") {
        let start = i + off;
        let word_start = !code[..start].chars().next_back().is_some_and(is_ident);
        let end = code[start..]
            .find(|c: char| !is_ident(c))
            .map_or(code.len(), |e| start + e);
        let word = &code[start..end];
        let called = code[end..].trim_start().starts_with('(');
        if word_start
            && called
            && ENTRY_PREFIXES
                .iter()
                .any(|p| word.len() > p.len() && word.starts_with(p))
            && !found.iter().any(|f| f == word)
        {
            found.push(word.to_string());
        }
        i = end.max(start + 2);
    }
    found
}

/// Comments out `#include <optix….h>` and `#include "optix….h"` lines: the compilers put the
/// device header in the translation unit themselves.
///
/// ```
/// let s = oxray_core::source::strip_optix_includes("#include <optix.h>\n#include <cmath>\n");
/// assert_eq!(s, "// (oxray device header) #include <optix.h>\n#include <cmath>\n");
/// ```
#[must_use]
pub fn strip_optix_includes(source: &str) -> String {
    let mut out = String::with_capacity(source.len());
    for line in source.lines() {
        let t = line.trim_start();
        let is_optix = t.starts_with('#')
            && t[1..].trim_start().starts_with("include")
            && t.split(['<', '"'])
                .nth(1)
                .is_some_and(|h| h.trim_start().starts_with("optix"));
        if is_optix {
            out.push_str("// (oxray device header) ");
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// The names of variables a module declares in the single-declaration form
/// `extern "C" __constant__ T name;` (or `__device__`). CUDA compiles such a declaration as the
/// variable's definition (the guide's launch-parameter variable is usually declared so); a
/// host compiler takes it for a declaration only, so the CPU backend defines these variables.
///
/// ```
/// let src = "extern \"C\" __constant__ Params params;\nextern \"C\" { __constant__ int n; }\n";
/// assert_eq!(oxray_core::source::extern_c_variables(src), ["params"]);
/// ```
#[must_use]
pub fn extern_c_variables(source: &str) -> Vec<String> {
    let code = code_only(source);
    let mut names = Vec::new();
    for (i, _) in code.match_indices("extern") {
        let after = i + "extern".len();
        let lit = after + (code[after..].len() - code[after..].trim_start().len());
        // String contents are blanked in `code`; offsets are the source's.
        if !source.get(lit..).is_some_and(|r| r.starts_with("\"C\"")) {
            continue;
        }
        let rest = &code[lit + 3..];
        let rest = rest.trim_start();
        let Some(rest) = rest
            .strip_prefix("__constant__")
            .or_else(|| rest.strip_prefix("__device__"))
        else {
            continue;
        };
        let Some(end) = rest.find(';') else {
            continue;
        };
        let decl = &rest[..end];
        if decl.contains(['{', '(', '=', '}']) {
            continue;
        }
        // The declarator's name: the last identifier before any array bounds.
        let decl = decl.split('[').next().unwrap_or("").trim_end();
        let name: String = decl
            .chars()
            .rev()
            .take_while(|&c| is_ident(c))
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        if !name.is_empty()
            && !name.starts_with(|c: char| c.is_ascii_digit())
            && !names.contains(&name)
        {
            names.push(name);
        }
    }
    names
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_skip_comments_strings_and_longer_names() {
        let src = r#"
            /* __raygen__commented() */
            const char* s = "__miss__in_a_string()";
            extern "C" __global__ void __raygen__a() { helper__raygen__x(); }
            extern "C" __global__ void __closesthit__c ();
            extern "C" __global__ void __closesthit__c () {}
            extern "C" __device__ float3 __direct_callable__shade(float3 n) { return n; }
            static int __raygen__; // no name after the prefix
        "#;
        assert_eq!(
            entries(src),
            ["__raygen__a", "__closesthit__c", "__direct_callable__shade"]
        );
        assert!(has_entry(src, "__closesthit__c"));
        assert!(!has_entry(src, "__raygen__commented"));
        assert!(!has_entry(src, "__raygen__x"));
    }

    #[test]
    fn extern_c_declarations_are_found_and_definitions_are_not() {
        let src = "extern \"C\" __constant__ Params params;\n\
                   extern \"C\" __device__ float table[16];\n\
                   extern \"C\" __device__ int f(int x);\n\
                   extern \"C\" __device__ int g = 3;\n\
                   extern \"C\" { __constant__ Params other; }\n\
                   extern \"C\" __constant__ Params params;\n";
        assert_eq!(extern_c_variables(src), ["params", "table"]);
    }
}
