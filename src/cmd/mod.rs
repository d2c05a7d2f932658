//! One module per sub-command.

//!
//! By area: [`decode`] (one module per protocol), [`mock`] (one per mock device, and the
//! whole world), [`drive`] (both bases, and `ima demo square`).

pub mod camera;
pub mod commander;
pub mod compass;
pub mod decode;
pub mod demo;
pub mod drive;
pub mod experiment;
#[cfg(test)]
mod layout_tests;
pub mod mock;
pub mod num;
pub mod output;
pub mod peer;
pub mod replay;
pub mod run;
pub mod san;
pub mod scan;

// The paths these modules had before the split by area, still used by `demo`, `run` and
// `crate::stack` (which other work is moving into `ima_agents::runtime`); switch those to the
// new paths and drop the aliases once that lands.
pub use self::drive::square as demo_square;
pub use self::mock::world as mock_world;

/// `--web [ADDR]` and `--web-token` of `ima commander` and `ima demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct WebArgs {
    /// Serve the console in the browser on ADDR (default 127.0.0.1:8080; port 0 picks a free
    /// one). Beyond loopback it asks for a token (see --web-token).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = crate::web::DEFAULT_ADDR)]
    pub web: Option<String>,
    /// The console's token when bound beyond loopback (a random one is made and printed
    /// when absent); also required on loopback when given.
    #[arg(
        long,
        value_name = "TOKEN",
        requires = "web",
        env = "IMA_WEB_TOKEN",
        hide_env_values = true
    )]
    pub web_token: Option<String>,
}

impl WebArgs {
    /// Checks `--web` and `--web-token` before any work (the address parses, the token is
    /// usable); the address when `--web` was given.
    pub fn check(&self) -> anyhow::Result<Option<std::net::SocketAddr>> {
        let Some(addr) = &self.web else {
            return Ok(None);
        };
        let addr = crate::web::parse_addr(addr)?;
        if let Some(t) = &self.web_token {
            anyhow::ensure!(
                t.len() >= 8
                    && t.bytes()
                        .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_'),
                "--web-token: at least 8 letters, digits, '-' or '_'"
            );
        }
        Ok(Some(addr))
    }

    /// Start the console when `--web` was given: the console and its server. The URL goes
    /// to stderr (`ima: web console at URL`).
    pub fn start(
        &self,
        mode: &str,
        colours: Vec<String>,
        ops: Option<tokio::sync::mpsc::UnboundedSender<ima_agents::runtime::commander::Operator>>,
    ) -> anyhow::Result<Option<(std::sync::Arc<crate::web::Console>, crate::web::WebServer)>> {
        let Some(addr) = self.check()? else {
            return Ok(None);
        };
        let token = match &self.web_token {
            Some(t) => Some(t.clone()),
            None if !addr.ip().is_loopback() => Some(crate::web::random_token()),
            None => None,
        };
        let console = crate::web::Console::new(mode, colours, ops, token.clone());
        let server = crate::web::start(std::sync::Arc::clone(&console), addr)?;
        // The URL alone on its line, to be copied or read by a script.
        eprintln!(
            "ima: web console at {}",
            crate::web::url(server.addr, token.as_deref())
        );
        if server.addr.ip().is_unspecified() {
            let local = if server.addr.is_ipv4() {
                "127.0.0.1"
            } else {
                "[::1]"
            };
            eprintln!("ima: from another machine, put this machine's address in place of {local}");
        }
        Ok(Some((console, server)))
    }
}

/// `  COLOUR: why` for each failed target whose reason the commander knows (it gave up, it
/// was cancelled, interrupted): what the text summaries of `ima commander` and `ima demo`
/// print under their counts.
pub fn failure_lines(
    outcomes: &[ima_agents::runtime::commander::TargetOutcome],
) -> impl Iterator<Item = String> + '_ {
    use ima_agents::runtime::commander::TargetState;
    outcomes
        .iter()
        .filter(|o| o.state != TargetState::Done)
        .filter_map(|o| Some(format!("  {}: {}", o.target, o.reason.as_ref()?)))
}

/// Checks that every target colour is one of `known`; the error lists the known colours
/// (`what` says where they come from, e.g. "the world's objects").
///
/// # Errors
/// More targets than a series holds; the first unknown colour, with the known ones.
pub fn check_colours(targets: &[String], known: &[String], what: &str) -> anyhow::Result<()> {
    use ima_agents::mission::commander::MAX_SERIES;
    anyhow::ensure!(
        targets.len() <= MAX_SERIES,
        "--targets names {} targets; a series holds at most {MAX_SERIES}",
        targets.len()
    );
    for t in targets {
        anyhow::ensure!(
            known.contains(t),
            "unknown target colour {t:?}; {what} are: {}",
            if known.is_empty() {
                "none (nothing to find)".to_owned()
            } else {
                known.join(", ")
            }
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A colour nobody knows names the known ones, or says there are none (it printed an
    /// empty list); a series longer than one holds is refused.
    #[test]
    fn target_colours_are_checked() {
        let red = vec!["red".to_owned()];
        assert!(check_colours(&red, &red, "the world's object colours").is_ok());
        let e = check_colours(&red, &[], "the world's object colours").unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown target colour \"red\"; the world's object colours are: none (nothing to find)"
        );
        let many = vec!["red".to_owned(); ima_agents::mission::commander::MAX_SERIES + 1];
        let e = check_colours(&many, &red, "x").unwrap_err().to_string();
        assert!(
            e.contains("names 257 targets; a series holds at most 256"),
            "{e}"
        );
    }
}
