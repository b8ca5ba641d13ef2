//! ROS 2 names as rcl resolves them (REP/design article "Topic and Service name mapping to DDS",
//! rcl's `rcl_expand_topic_name` and its remapping rules), and the node-name patterns of
//! parameters files (rclcpp's `parameter_map_from`): pure functions, no I/O.
//!
//! - An absolute name (`/ball/state`) is itself; a relative one (`ball/state`) is put in the
//!   node's namespace (`/robot1/ball/state`); a private one (`~/reset`, or `~`) in the node's
//!   own (`/robot1/ttball/reset`).
//! - A remap rule `FROM:=TO` replaces a name whose resolved form equals FROM resolved; TO is
//!   resolved the same way.
//! - A parameters file's node key is a fully qualified node name in which `*` stands for one
//!   namespace level or name and `**` for any number of them (`/**`, `/**/ttball`,
//!   `/robot1/ttball`); a key without a leading `/` is taken from the root (`ttball` is
//!   `/ttball`).

/// Why a name is not a valid ROS 2 topic or service name, if it is not: tokens of letters,
/// digits and underscores, not starting with a digit, separated by single slashes; absolute
/// (`/x`), relative (`x`) or private (`~`, `~/x`).
pub fn name_problem(name: &str) -> Option<&'static str> {
    if name.is_empty() {
        return Some(
            "it must not be empty; e.g. \"ball/state\" (in the node's namespace) or \"/ball/state\"",
        );
    }
    if name == "~" {
        return None;
    }
    let tokens = name
        .strip_prefix("~/")
        .or_else(|| name.strip_prefix('/'))
        .unwrap_or(name);
    if name.starts_with('~') && !name.starts_with("~/") {
        return Some("'~' may only start a name as \"~\" or \"~/...\" (the node's private names)");
    }
    token_problem(tokens)
}

/// Checks the tokens of a name (the part after a leading `/` or `~/`).
pub(crate) fn token_problem(tokens: &str) -> Option<&'static str> {
    for token in tokens.split('/') {
        if token.is_empty() {
            return Some("it must not contain \"//\" or end with '/'");
        }
        if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Some("use only letters, digits, '_' and '/'");
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            return Some("no part between slashes may start with a digit");
        }
    }
    None
}

/// The node's fully qualified name: `/node` in the root namespace (`""` or `"/"`), else
/// `/namespace/node`.
pub fn fully_qualified_node_name(namespace: &str, node: &str) -> String {
    let namespace = namespace.trim_end_matches('/');
    format!("{namespace}/{node}")
}

/// `name` resolved in the namespace `namespace` of node `node` (see the module docs). A name
/// that [`name_problem`] refuses is returned as given.
pub fn resolve(name: &str, namespace: &str, node: &str) -> String {
    let namespace = namespace.trim_end_matches('/');
    if name == "~" {
        fully_qualified_node_name(namespace, node)
    } else if let Some(rest) = name.strip_prefix("~/") {
        format!("{}/{rest}", fully_qualified_node_name(namespace, node))
    } else if name.starts_with('/') {
        name.to_owned()
    } else {
        format!("{namespace}/{name}")
    }
}

/// Whether a parameters file's node key (`/**`, `/**/ttball`, `ttball`, `/robot1/ttball`,
/// `/*/ttball`) applies to the node of fully qualified name `node_fqn`.
pub fn node_key_matches(key: &str, node_fqn: &str) -> bool {
    let key = key.trim_start_matches('/');
    let pattern: Vec<&str> = key.split('/').filter(|s| !s.is_empty()).collect();
    let name: Vec<&str> = node_fqn.split('/').filter(|s| !s.is_empty()).collect();
    segments_match(&pattern, &name)
}

fn segments_match(pattern: &[&str], name: &[&str]) -> bool {
    match pattern.split_first() {
        None => name.is_empty(),
        Some((&"**", rest)) => (0..=name.len()).any(|skip| segments_match(rest, &name[skip..])),
        Some((&segment, rest)) => name.split_first().is_some_and(|(&first, tail)| {
            (segment == "*" || segment == first) && segments_match(rest, tail)
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_resolve_as_rcl_resolves_them() {
        for (name, ns, expected) in [
            ("ball/state", "", "/ball/state"),
            ("ball/state", "/", "/ball/state"),
            ("ball/state", "/robot1", "/robot1/ball/state"),
            ("ball/state", "/a/b/", "/a/b/ball/state"),
            ("/diagnostics", "/robot1", "/diagnostics"),
            ("~/reset", "/robot1", "/robot1/ttball/reset"),
            ("~/reset", "", "/ttball/reset"),
            ("~", "/robot1", "/robot1/ttball"),
        ] {
            assert_eq!(resolve(name, ns, "ttball"), expected, "{name} in {ns:?}");
        }
        assert_eq!(fully_qualified_node_name("", "ttball"), "/ttball");
        assert_eq!(fully_qualified_node_name("/r", "ttball"), "/r/ttball");
    }

    #[test]
    fn names_are_checked() {
        for good in ["ball/state", "/ball/state", "~", "~/reset", "a_1/b2"] {
            assert_eq!(name_problem(good), None, "{good}");
        }
        for bad in [
            "",
            "/",
            "a//b",
            "a/",
            "1a",
            "~x",
            "a b",
            "/ball/~/x",
            "ball-state",
        ] {
            assert!(name_problem(bad).is_some(), "{bad}");
        }
    }

    #[test]
    fn node_keys_match_as_rclcpp_matches_them() {
        for (key, fqn, expected) in [
            ("/**", "/ttball", true),
            ("/**", "/robot1/ttball", true),
            ("/**/ttball", "/ttball", true),
            ("/**/ttball", "/a/b/ttball", true),
            ("/**/ttball", "/a/b/other", false),
            ("ttball", "/ttball", true),
            ("ttball", "/robot1/ttball", false),
            ("/ttball", "/ttball", true),
            ("/robot1/ttball", "/robot1/ttball", true),
            ("/robot1/ttball", "/robot2/ttball", false),
            ("/*/ttball", "/robot1/ttball", true),
            ("/*/ttball", "/ttball", false),
            ("/*", "/ttball", true),
            ("/*", "/robot1/ttball", false),
            ("camera_driver", "/ttball", false),
        ] {
            assert_eq!(node_key_matches(key, fqn), expected, "{key} vs {fqn}");
        }
    }
}
