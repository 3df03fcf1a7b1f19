//! How every tool of the workspace writes values into its one-line messages: floats short
//! ([`num`]), an error with its causes on one line ([`error_line`]), paths quoted
//! ([`crate::input::quoted`]). The CLI, the Python extension and the C ABI print the same
//! text for the same error.

/// A float for messages: plain when short, scientific otherwise (1e308 is not 309 digits).
pub fn num(x: f64) -> String {
    let plain = format!("{x}");
    if plain.len() <= 12 {
        plain
    } else {
        format!("{x:e}")
    }
}

/// An error and its causes on one line, each cause once: errors that put their source's
/// text into their own message (`"{path}: {source}"`) and also return it from `source()`
/// would otherwise print the OS error twice.
pub fn error_line(e: &(dyn std::error::Error + 'static)) -> String {
    let mut msg = String::new();
    let mut cause = Some(e);
    while let Some(c) = cause {
        let text = c.to_string();
        if !msg.contains(&text) {
            if !msg.is_empty() {
                msg.push_str(": ");
            }
            msg.push_str(&text);
        }
        cause = c.source();
    }
    msg.replace(['\n', '\r'], " ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("a.pin: {0}")]
    struct Outer(#[source] std::io::Error);

    #[test]
    fn numbers_stay_short() {
        assert_eq!(num(1e308), "1e308");
        assert_eq!(num(0.25), "0.25");
        assert_eq!(num(f64::INFINITY), "inf");
    }

    #[test]
    fn each_cause_once_on_one_line() {
        let e = Outer(std::io::Error::other("disk\nfull"));
        assert_eq!(error_line(&e), "a.pin: disk full");
    }
}
