//! The duration convention of every hng configuration: seconds, as numbers, in keys ending in
//! `_s`. A key of an older spelling (`dt`, `duration`) is an unknown field to serde; this names
//! its new spelling.

/// For serde's message about an unknown key whose `_s` spelling the type has ("unknown field
/// `dt`, expected one of `name`, `dt_s`, ..."), the message a user needs: "`dt` is now `dt_s`
/// (seconds)". `None` for any other message.
#[must_use]
pub fn renamed_to_seconds(message: &str) -> Option<String> {
    let rest = message.trim().strip_prefix("unknown field `")?;
    let (old, expected) = rest.split_once('`')?;
    let new = format!("{old}_s");
    expected
        .contains(&format!("`{new}`"))
        .then(|| format!("`{old}` is now `{new}` (seconds)"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_old_duration_key_is_named_with_its_new_spelling_and_nothing_else_is() {
        assert_eq!(
            renamed_to_seconds("unknown field `dt`, expected one of `name`, `dt_s`, `robot`"),
            Some("`dt` is now `dt_s` (seconds)".to_owned())
        );
        assert_eq!(
            renamed_to_seconds("unknown field `duration`, expected `duration_s`"),
            Some("`duration` is now `duration_s` (seconds)".to_owned())
        );
        assert_eq!(
            renamed_to_seconds("unknown field `colour`, expected one of `name`, `color`"),
            None
        );
        // `d` is not renamed just because `dt_s` starts with it.
        assert_eq!(
            renamed_to_seconds("unknown field `d`, expected one of `dt_s`"),
            None
        );
        assert_eq!(renamed_to_seconds("invalid type: string"), None);
    }

    #[test]
    fn serde_says_it_so_for_a_real_config() {
        #[derive(Debug, serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        #[allow(dead_code)]
        struct Config {
            period_s: f64,
        }
        let e = toml::from_str::<Config>("period = 0.1\n").expect_err("an old key");
        assert_eq!(
            renamed_to_seconds(e.message()),
            Some("`period` is now `period_s` (seconds)".to_owned())
        );
    }
}
