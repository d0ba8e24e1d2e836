//! The rules for names that prefix parameters (element and group names) and the names
//! reserved for the modal parameters. Both the element library ([`crate::element`]) and the
//! parameter identity ([`crate::param`]) use them, so they live below both.

/// Whether `s` is a valid element or group name: ASCII letters, digits, `_` and `-`.
pub fn is_valid_name(s: &str) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// `Some(r)` (0-based) when `s` is `modeN` with `N ≥ 1`.
pub(crate) fn mode_number(s: &str) -> Option<usize> {
    let digits = s.strip_prefix("mode")?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) || digits.len() > 9 {
        return None;
    }
    digits.parse::<usize>().ok()?.checked_sub(1)
}
