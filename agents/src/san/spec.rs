//! The TOML format of a network (networks are data, not code).
//!
//! ```toml
//! name = "maes-toy"                      # required
//! description = "free text"              # optional
//! goals = ["board-sanded", "self-painted"]  # propositions the network strives to make true
//!
//! [params]                               # optional; every key optional (Maes's toy values)
//! pi = 20.0          # π: mean activation; Σα is kept at n·π
//! theta = 45.0       # θ: initial firing threshold
//! phi = 20.0         # φ: energy each true proposition injects
//! gamma = 70.0       # γ: energy each goal injects
//! delta = 50.0       # δ: energy each protected goal takes away
//! theta_decay = 0.9  # θ ← θ·theta_decay when nothing fires
//! normalization = "exact"   # "exact": scale Σα to n·π every step; "scale-down": only when above
//! reset_fired = true        # a fired module's activation drops to 0
//!
//! [[condition]]                 # one per proposition; every proposition must be declared
//! name = "hand-is-empty"
//! initial = 2                   # bool (true/false) or a count (a multiset proposition)
//! source = "local"              # optional, free text: which agent feeds it (doc only)
//! doc = "..."                   # optional
//!
//! [[module]]                    # competency modules, in priority order
//! name = "pick-up-sander"
//! weight = 1.0                  # optional (default 1): breaks activation ties, higher wins
//! pre = ["sander-somewhere", "hand-is-empty"]   # preconditions (all must be true)
//! add = ["sander-in-hand"]      # made true when it runs
//! del = ["sander-somewhere", "hand-is-empty"]   # made false when it runs
//! doc = "..."                   # optional
//! ```
//!
//! A condition whose `initial` is a boolean is a *flag* (its count never exceeds 1); one whose
//! `initial` is an integer is a *counter* (multiset semantics, needed by Maes's two-handed
//! robot). Unknown keys are errors, so a typo cannot silently change a network.

use serde::Deserialize;

/// Global parameters (research note §2.2). Defaults are the values of Maes's toy example.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Params {
    /// π, mean activation level.
    pub pi: f64,
    /// θ, initial firing threshold.
    pub theta: f64,
    /// φ, energy injected per true proposition.
    pub phi: f64,
    /// γ, energy injected per goal.
    pub gamma: f64,
    /// δ, energy taken away per protected goal.
    pub delta: f64,
    /// Factor applied to θ when no module fires (Maes: 0.9).
    pub theta_decay: f64,
    /// How the total activation is kept at n·π.
    pub normalization: Normalization,
    /// Whether a fired module's activation is reset to 0.
    pub reset_fired: bool,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            pi: 20.0,
            theta: 45.0,
            phi: 20.0,
            gamma: 70.0,
            delta: 50.0,
            theta_decay: 0.9,
            normalization: Normalization::Exact,
            reset_fired: true,
        }
    }
}

/// How activation is normalised after each spreading step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Normalization {
    /// Scale so that Σα = n·π exactly (Maes's description).
    Exact,
    /// Scale down only when Σα exceeds n·π (some reproductions).
    ScaleDown,
}

/// Initial value of a condition: `true`/`false`, or a count from 0 to `u32::MAX`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Initial {
    /// A flag, initially true or false.
    Flag(bool),
    /// A counter (multiset proposition) with this many instances.
    Count(u32),
}

/// By hand, so a wrong value is named with what is allowed (serde's untagged enum said only
/// "data did not match any variant").
impl<'de> Deserialize<'de> for Initial {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Initial;
            fn expecting(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                write!(f, "true, false, or a count from 0 to {}", u32::MAX)
            }
            fn visit_bool<E: serde::de::Error>(self, v: bool) -> Result<Initial, E> {
                Ok(Initial::Flag(v))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Initial, E> {
                u32::try_from(v)
                    .map(Initial::Count)
                    .map_err(|_| E::invalid_value(serde::de::Unexpected::Unsigned(v), &self))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Initial, E> {
                u64::try_from(v)
                    .map_err(|_| E::invalid_value(serde::de::Unexpected::Signed(v), &self))
                    .and_then(|v| self.visit_u64(v))
            }
        }
        d.deserialize_any(V)
    }
}

impl Default for Initial {
    fn default() -> Self {
        Self::Flag(false)
    }
}

/// A condition node: a proposition whose truth agents feed in.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConditionSpec {
    /// Proposition name.
    pub name: String,
    /// Initial value (default `false`).
    #[serde(default)]
    pub initial: Initial,
    /// Which agent feeds it (documentation only).
    #[serde(default)]
    pub source: Option<String>,
    /// Free text.
    #[serde(default)]
    pub doc: String,
}

fn one() -> f64 {
    1.0
}

/// A competency module.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModuleSpec {
    /// Module name.
    pub name: String,
    /// Tie-breaking weight (higher wins), default 1.
    #[serde(default = "one")]
    pub weight: f64,
    /// Preconditions.
    #[serde(default)]
    pub pre: Vec<String>,
    /// Add list.
    #[serde(default)]
    pub add: Vec<String>,
    /// Delete list.
    #[serde(default)]
    pub del: Vec<String>,
    /// Free text.
    #[serde(default)]
    pub doc: String,
}

/// A whole network as written in TOML.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkSpec {
    /// Network name.
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Goal propositions.
    #[serde(default)]
    pub goals: Vec<String>,
    /// Parameters.
    #[serde(default)]
    pub params: Params,
    /// Condition nodes.
    #[serde(default, rename = "condition")]
    pub conditions: Vec<ConditionSpec>,
    /// Competency modules.
    #[serde(default, rename = "module")]
    pub modules: Vec<ModuleSpec>,
}

/// Why a network description is invalid.
#[derive(Debug, Clone, PartialEq)]
pub enum SpecError {
    /// Not valid TOML, or not the documented shape (the parser's message).
    Toml(String),
    /// No modules.
    NoModules,
    /// Two conditions share a name.
    DuplicateCondition(String),
    /// Two modules share a name.
    DuplicateModule(String),
    /// A module names an undeclared proposition.
    UnknownProposition {
        /// The module.
        module: String,
        /// The undeclared proposition.
        name: String,
    },
    /// A goal names an undeclared proposition.
    UnknownGoal(String),
    /// A parameter is out of range (its name).
    BadParam(&'static str),
    /// A module weight is not finite.
    BadWeight(String),
    /// A condition or a module (which of the two) has an empty or blank name: nothing could
    /// name it in a precondition, a goal, a status or a log.
    EmptyName(&'static str),
}

/// Largest value of an energy parameter (`pi`, `phi`, `gamma`, `delta`): far above
/// any useful network (the thesis uses tens), low enough that sums and ratios stay finite.
pub const MAX_ENERGY: f64 = 1e6;

/// The allowed range of parameter `name`, in words.
fn param_range(name: &str) -> &'static str {
    match name {
        "pi" | "gamma" => "a finite number in (0, 1000000]",
        "theta" => "a finite number above 0",
        "phi" | "delta" => "a finite number in [0, 1000000]",
        "theta_decay" => "a number in (0, 1)",
        _ => "see the network documentation",
    }
}

impl core::fmt::Display for SpecError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Toml(m) => write!(f, "network TOML: {m}"),
            Self::NoModules => f.write_str("network has no modules"),
            Self::DuplicateCondition(n) => write!(f, "condition `{n}` declared twice"),
            Self::DuplicateModule(n) => write!(f, "module `{n}` declared twice"),
            Self::UnknownProposition { module, name } => {
                write!(f, "module `{module}` uses undeclared proposition `{name}`")
            }
            Self::UnknownGoal(n) => write!(f, "goal `{n}` is not a declared condition"),
            Self::BadParam(p) => write!(f, "parameter `{p}` is out of range: {}", param_range(p)),
            Self::BadWeight(m) => write!(f, "module `{m}` has a non-finite weight"),
            Self::EmptyName(what) => write!(f, "a {what} has an empty name"),
        }
    }
}

impl std::error::Error for SpecError {}

impl NetworkSpec {
    /// Parse the TOML text (shape only; [`crate::san::Network::new`] validates the rest).
    ///
    /// # Errors
    /// [`SpecError::Toml`].
    pub fn from_toml(text: &str) -> Result<Self, SpecError> {
        toml::from_str(text)
            .map_err(|e| SpecError::Toml(ima_hal::file::located(text, e.span(), e.message())))
    }
}
