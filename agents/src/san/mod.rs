//! Spreading Activation Network (SAN): action selection after Pattie Maes, "How to do the
//! right thing" (Connection Science 1(3), 1989), as the thesis's Self Agents use it.
//!
//! A network is **data**: condition nodes (propositions) and competency modules
//! `(pre, add, del, weight)` written in TOML ([`spec`] documents the format; the example
//! networks live in `agents/networks/`). Links are derived from the lists: successor
//! (`add_x ∩ pre_y`), predecessor (the reverse) and conflicter (`pre_x ∩ del_y`).
//!
//! # One step ([`Network::step`]), research note §2.3
//!
//! With `α'` the activations after the previous step, `S` the true propositions, `G` the
//! goals not yet true and `R` the goals already true (the *protected* goals), and `M(p)`,
//! `A(p)`, `U(p)` the modules having `p` in their pre/add/del list:
//!
//! 1. state: each true `p ∈ pre_x` gives x `φ / |M(p)| / |pre_x|`;
//! 2. goals: each `p ∈ G ∩ add_x` gives x `γ / |A(p)| / |add_x|`;
//! 3. protected goals: each `p ∈ R ∩ del_x` takes `δ / |U(p)| / |del_x|` from x;
//! 4. backward: a non-executable x, for each false `p ∈ pre_x`, gives each `y ∈ A(p)`
//!    `α'_x / |A(p)| / |add_y|`;
//! 5. forward: an executable x, for each false `p ∈ add_x`, gives each `y ∈ M(p)`
//!    `α'_x·(φ/γ) / |M(p)| / |pre_y|`;
//! 6. inhibition: every x, for each true `p ∈ pre_x`, takes from each `y ∈ U(p)`, `y ≠ x`,
//!    `min(α'_x·(δ/γ) / |U(p)| / |del_y|, α'_y)`; when x and y conflict with each other only
//!    the one with the strictly higher `α'` inhibits;
//! 7. sum onto `α'`, clamp at 0, normalise (Σα = n·π exactly, or only scale down —
//!    [`Normalization`]);
//! 8. select: the executable module with the highest α ≥ θ fires (ties within 1e-9: higher
//!    weight, then earlier declaration). θ returns to θ₀ after a firing (and the fired
//!    module's α drops to 0 if `reset_fired`); if nothing fires, θ ← θ·`theta_decay`.
//!
//! # Choices where Maes is silent or the thesis unknown
//!
//! * The state is a multiset of propositions: counters for conditions declared with an
//!   integer, flags (0/1) for booleans. A proposition is true when its count is ≥ 1.
//! * Achieved goals are protected *while they are true*: `G` and `R` are recomputed from the
//!   state each step, so an undone goal is pursued again.
//! * [`Network::step`] only chooses; the fired module's action is the caller's business, and
//!   the world reports back through [`Network::set_condition`] (agents, local or remote via
//!   messages). [`Network::simulate_step`] instead applies the add/delete lists itself, the
//!   closed-world simulation Maes ran (delete first, then add).
//! * Deterministic: no hash-order iteration, no randomness, no clock.

pub mod spec;

use std::collections::HashMap;

use serde::Serialize;

pub use spec::{ConditionSpec, Initial, ModuleSpec, NetworkSpec, Normalization, Params, SpecError};

/// An operation named a proposition or module the network does not have.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SanError {
    /// No condition of that name.
    UnknownCondition(String),
}

impl core::fmt::Display for SanError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::UnknownCondition(n) => write!(f, "unknown condition `{n}`"),
        }
    }
}

impl std::error::Error for SanError {}

#[derive(Debug, Clone)]
struct Module {
    name: String,
    weight: f64,
    pre: Vec<usize>,
    add: Vec<usize>,
    del: Vec<usize>,
}

/// One module's line in a [`StepTrace`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModuleTrace {
    /// Module name.
    pub name: String,
    /// Activation after spreading (before a firing reset).
    pub activation: f64,
    /// Whether all its preconditions were true.
    pub executable: bool,
}

/// Everything that happened in one step.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StepTrace {
    /// Step number, from 1.
    pub step: u64,
    /// Threshold θ the selection used.
    pub threshold: f64,
    /// Every module, in declaration order.
    pub modules: Vec<ModuleTrace>,
    /// The module that fired, if any.
    pub fired: Option<String>,
    /// θ after the step.
    pub next_threshold: f64,
    /// True propositions after the step, in declaration order, repeated once per instance
    /// (at most 64 times, to keep traces small).
    pub state: Vec<String>,
    /// Goals not yet true after the step.
    pub goals: Vec<String>,
    /// Goals already true (protected) after the step.
    pub protected: Vec<String>,
}

/// A running spreading activation network. See the [module docs](self).
#[derive(Debug, Clone)]
pub struct Network {
    name: String,
    params: Params,
    conditions: Vec<String>,
    capacity: Vec<u32>,
    index: HashMap<String, usize>,
    modules: Vec<Module>,
    /// |M(p)|, |A(p)|, |U(p)| and the module lists A(p), M(p), U(p).
    m_of: Vec<Vec<usize>>,
    a_of: Vec<Vec<usize>>,
    u_of: Vec<Vec<usize>>,
    count: Vec<u32>,
    goal: Vec<bool>,
    activation: Vec<f64>,
    theta: f64,
    step: u64,
}

fn dedup(v: &mut Vec<usize>) {
    let mut seen = Vec::with_capacity(v.len());
    v.retain(|x| {
        if seen.contains(x) {
            false
        } else {
            seen.push(*x);
            true
        }
    });
}

impl Network {
    /// Validate a spec and build the network in its initial state.
    ///
    /// # Errors
    /// [`SpecError`] for duplicates, undeclared propositions, bad parameters or weights.
    pub fn new(spec: &NetworkSpec) -> Result<Self, SpecError> {
        let p = spec.params;
        // Injected energies are bounded (spec::MAX_ENERGY) so that their sums and ratios stay finite.
        let energy = |v: f64, zero_ok: bool| {
            v.is_finite() && v <= spec::MAX_ENERGY && (v > 0.0 || (zero_ok && v == 0.0))
        };
        let checks: [(&'static str, bool); 7] = [
            ("pi", energy(p.pi, false)),
            // A threshold, not an injected energy: only finite and positive (a huge one
            // stalls the network, which then falls back to the strongest module).
            ("theta", p.theta.is_finite() && p.theta > 0.0),
            ("phi", energy(p.phi, true)),
            ("gamma", energy(p.gamma, false)),
            ("delta", energy(p.delta, true)),
            (
                "theta_decay",
                p.theta_decay.is_finite() && p.theta_decay > 0.0 && p.theta_decay < 1.0,
            ),
            ("modules", !spec.modules.is_empty()),
        ];
        for (name, ok) in checks {
            if !ok {
                return Err(if name == "modules" {
                    SpecError::NoModules
                } else {
                    SpecError::BadParam(name)
                });
            }
        }
        let mut index = HashMap::new();
        let mut conditions = Vec::new();
        let mut capacity = Vec::new();
        let mut count = Vec::new();
        for c in &spec.conditions {
            if c.name.trim().is_empty() {
                return Err(SpecError::EmptyName("condition"));
            }
            if index.insert(c.name.clone(), conditions.len()).is_some() {
                return Err(SpecError::DuplicateCondition(c.name.clone()));
            }
            conditions.push(c.name.clone());
            let (cap, init) = match c.initial {
                Initial::Flag(b) => (1, u32::from(b)),
                Initial::Count(n) => (u32::MAX, n),
            };
            capacity.push(cap);
            count.push(init);
        }
        let mut modules = Vec::new();
        let mut names = HashMap::new();
        for m in &spec.modules {
            if m.name.trim().is_empty() {
                return Err(SpecError::EmptyName("module"));
            }
            if names.insert(m.name.clone(), ()).is_some() {
                return Err(SpecError::DuplicateModule(m.name.clone()));
            }
            if !m.weight.is_finite() {
                return Err(SpecError::BadWeight(m.name.clone()));
            }
            let resolve = |list: &[String]| -> Result<Vec<usize>, SpecError> {
                let mut v = list
                    .iter()
                    .map(|n| {
                        index
                            .get(n)
                            .copied()
                            .ok_or_else(|| SpecError::UnknownProposition {
                                module: m.name.clone(),
                                name: n.clone(),
                            })
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                dedup(&mut v);
                Ok(v)
            };
            modules.push(Module {
                name: m.name.clone(),
                weight: m.weight,
                pre: resolve(&m.pre)?,
                add: resolve(&m.add)?,
                del: resolve(&m.del)?,
            });
        }
        let np = conditions.len();
        let (mut m_of, mut a_of, mut u_of) = (vec![vec![]; np], vec![vec![]; np], vec![vec![]; np]);
        for (i, m) in modules.iter().enumerate() {
            for &p in &m.pre {
                m_of[p].push(i);
            }
            for &p in &m.add {
                a_of[p].push(i);
            }
            for &p in &m.del {
                u_of[p].push(i);
            }
        }
        let mut goal = vec![false; np];
        for g in &spec.goals {
            let &i = index
                .get(g)
                .ok_or_else(|| SpecError::UnknownGoal(g.clone()))?;
            goal[i] = true;
        }
        let n = modules.len();
        Ok(Self {
            name: spec.name.clone(),
            params: p,
            conditions,
            capacity,
            index,
            modules,
            m_of,
            a_of,
            u_of,
            count,
            goal,
            activation: vec![0.0; n],
            theta: p.theta,
            step: 0,
        })
    }

    /// Parse TOML ([`spec`]) and build the network.
    ///
    /// # Errors
    /// [`SpecError`].
    pub fn from_toml(text: &str) -> Result<Self, SpecError> {
        Self::new(&NetworkSpec::from_toml(text)?)
    }

    /// The network's name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Parameters.
    #[must_use]
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Change parameters; θ is reset to the new θ₀.
    pub fn set_params(&mut self, params: Params) {
        self.params = params;
        self.theta = params.theta;
    }

    /// Current threshold θ.
    #[must_use]
    pub fn threshold(&self) -> f64 {
        self.theta
    }

    /// Module names in declaration order.
    pub fn module_names(&self) -> impl Iterator<Item = &str> {
        self.modules.iter().map(|m| m.name.as_str())
    }

    /// Condition names in declaration order.
    pub fn condition_names(&self) -> impl Iterator<Item = &str> {
        self.conditions.iter().map(String::as_str)
    }

    /// Current activations, in module declaration order.
    #[must_use]
    pub fn activations(&self) -> &[f64] {
        &self.activation
    }

    /// Whether each module is executable now (every precondition true), in module
    /// declaration order.
    #[must_use]
    pub fn executable_flags(&self) -> Vec<bool> {
        self.modules.iter().map(|m| self.executable(m)).collect()
    }

    /// Whether a condition is true (`None` if unknown).
    #[must_use]
    pub fn condition(&self, name: &str) -> Option<bool> {
        self.index
            .get(name)
            .and_then(|&i| self.count.get(i))
            .map(|&c| c > 0)
    }

    /// Set a condition from an agent's report (local, or remote through a message): `true`
    /// makes its count at least 1, `false` makes it 0.
    ///
    /// # Errors
    /// [`SanError::UnknownCondition`].
    pub fn set_condition(&mut self, name: &str, value: bool) -> Result<(), SanError> {
        let &i = self
            .index
            .get(name)
            .ok_or_else(|| SanError::UnknownCondition(name.to_owned()))?;
        if let Some(c) = self.count.get_mut(i) {
            *c = if value { (*c).max(1) } else { 0 };
        }
        Ok(())
    }

    /// Set the instance count of a proposition (capped at 1 for flags).
    ///
    /// # Errors
    /// [`SanError::UnknownCondition`].
    pub fn set_count(&mut self, name: &str, n: u32) -> Result<(), SanError> {
        let &i = self
            .index
            .get(name)
            .ok_or_else(|| SanError::UnknownCondition(name.to_owned()))?;
        if let (Some(c), Some(&cap)) = (self.count.get_mut(i), self.capacity.get(i)) {
            *c = n.min(cap);
        }
        Ok(())
    }

    /// Replace the whole state: every condition false, then one instance per listed name
    /// (a name listed twice gives a counter two instances).
    ///
    /// # Errors
    /// [`SanError::UnknownCondition`]; the state is unchanged then.
    pub fn set_state<S: AsRef<str>>(&mut self, names: &[S]) -> Result<(), SanError> {
        let mut count = vec![0_u32; self.conditions.len()];
        for n in names {
            let &i = self
                .index
                .get(n.as_ref())
                .ok_or_else(|| SanError::UnknownCondition(n.as_ref().to_owned()))?;
            if let (Some(c), Some(&cap)) = (count.get_mut(i), self.capacity.get(i)) {
                *c = c.saturating_add(1).min(cap);
            }
        }
        self.count = count;
        Ok(())
    }

    /// Replace the goal set.
    ///
    /// # Errors
    /// [`SanError::UnknownCondition`]; the goals are unchanged then.
    pub fn set_goals<S: AsRef<str>>(&mut self, names: &[S]) -> Result<(), SanError> {
        let mut goal = vec![false; self.conditions.len()];
        for n in names {
            let &i = self
                .index
                .get(n.as_ref())
                .ok_or_else(|| SanError::UnknownCondition(n.as_ref().to_owned()))?;
            if let Some(g) = goal.get_mut(i) {
                *g = true;
            }
        }
        self.goal = goal;
        Ok(())
    }

    fn is_true(&self, p: usize) -> bool {
        self.count.get(p).is_some_and(|&c| c > 0)
    }

    fn executable(&self, m: &Module) -> bool {
        m.pre.iter().all(|&p| self.is_true(p))
    }

    /// Whether `x` would inhibit `y` through some true precondition of x in y's delete list.
    fn conflicts(&self, x: usize, y: usize) -> bool {
        match (self.modules.get(x), self.modules.get(y)) {
            (Some(mx), Some(my)) => mx
                .pre
                .iter()
                .any(|&p| self.is_true(p) && my.del.contains(&p)),
            _ => false,
        }
    }

    /// Spread activation once and select (rules 1–8 of the module docs). The fired module's
    /// effects are *not* applied; see [`Network::simulate_step`].
    #[allow(clippy::indexing_slicing)] // all indices come from validated lists
    pub fn step(&mut self) -> StepTrace {
        let p = self.params;
        let n = self.modules.len();
        let prev = self.activation.clone();
        let mut delta = vec![0.0; n];
        let len = |v: &Vec<usize>| v.len().max(1) as f64;
        let exec: Vec<bool> = self.modules.iter().map(|m| self.executable(m)).collect();
        for (x, m) in self.modules.iter().enumerate() {
            for &q in &m.pre {
                if self.is_true(q) {
                    delta[x] += p.phi / len(&self.m_of[q]) / len(&m.pre);
                }
            }
            for &q in &m.add {
                if self.goal[q] && !self.is_true(q) {
                    delta[x] += p.gamma / len(&self.a_of[q]) / len(&m.add);
                }
            }
            for &q in &m.del {
                if self.goal[q] && self.is_true(q) {
                    delta[x] -= p.delta / len(&self.u_of[q]) / len(&m.del);
                }
            }
            if exec[x] {
                for &q in &m.add {
                    if !self.is_true(q) {
                        for &y in &self.m_of[q] {
                            delta[y] += prev[x] * (p.phi / p.gamma)
                                / len(&self.m_of[q])
                                / len(&self.modules[y].pre);
                        }
                    }
                }
            } else {
                for &q in &m.pre {
                    if !self.is_true(q) {
                        for &y in &self.a_of[q] {
                            delta[y] += prev[x] / len(&self.a_of[q]) / len(&self.modules[y].add);
                        }
                    }
                }
            }
            for &q in &m.pre {
                if !self.is_true(q) {
                    continue;
                }
                for &y in &self.u_of[q] {
                    if y == x || (self.conflicts(y, x) && prev[y] >= prev[x]) {
                        continue;
                    }
                    let take = (prev[x] * (p.delta / p.gamma)
                        / len(&self.u_of[q])
                        / len(&self.modules[y].del))
                    .min(prev[y]);
                    delta[y] -= take;
                }
            }
        }
        let mut act: Vec<f64> = prev
            .iter()
            .zip(&delta)
            .map(|(a, d)| (a + d).max(0.0))
            .collect();
        let sum: f64 = act.iter().sum();
        let target = n as f64 * p.pi;
        let scale = match p.normalization {
            Normalization::Exact if sum > 0.0 => target / sum,
            Normalization::ScaleDown if sum > target => target / sum,
            _ => 1.0,
        };
        for a in &mut act {
            *a *= scale;
        }
        let threshold = self.theta;
        let mut best: Option<usize> = None;
        for x in 0..n {
            if !exec[x] || act[x] < threshold {
                continue;
            }
            best = match best {
                None => Some(x),
                Some(b) => {
                    let tol = 1e-9 * act[b].abs().max(1.0);
                    if act[x] > act[b] + tol
                        || ((act[x] - act[b]).abs() <= tol
                            && self.modules[x].weight > self.modules[b].weight)
                    {
                        Some(x)
                    } else {
                        Some(b)
                    }
                }
            };
        }
        let modules = self
            .modules
            .iter()
            .zip(&act)
            .zip(&exec)
            .map(|((m, &a), &e)| ModuleTrace {
                name: m.name.clone(),
                activation: a,
                executable: e,
            })
            .collect();
        match best {
            Some(x) => {
                self.theta = p.theta;
                if p.reset_fired {
                    act[x] = 0.0;
                }
            }
            None => self.theta *= p.theta_decay,
        }
        self.activation = act;
        self.step += 1;
        let mut trace = StepTrace {
            step: self.step,
            threshold,
            modules,
            fired: best.map(|x| self.modules[x].name.clone()),
            next_threshold: self.theta,
            state: Vec::new(),
            goals: Vec::new(),
            protected: Vec::new(),
        };
        self.fill_state(&mut trace);
        trace
    }

    /// Apply a module's delete list, then its add list, to the state (closed-world
    /// simulation). Unknown names are ignored and return `false`.
    pub fn apply_effects(&mut self, module: &str) -> bool {
        let Some(m) = self.modules.iter().find(|m| m.name == module) else {
            return false;
        };
        let (del, add) = (m.del.clone(), m.add.clone());
        for p in del {
            if let Some(c) = self.count.get_mut(p) {
                *c = c.saturating_sub(1);
            }
        }
        for p in add {
            if let (Some(c), Some(&cap)) = (self.count.get_mut(p), self.capacity.get(p)) {
                *c = c.saturating_add(1).min(cap);
            }
        }
        true
    }

    /// [`Network::step`], then apply the fired module's effects; the trace shows the state
    /// after them.
    pub fn simulate_step(&mut self) -> StepTrace {
        let mut t = self.step();
        if let Some(f) = t.fired.clone() {
            self.apply_effects(&f);
            self.fill_state(&mut t);
        }
        t
    }

    fn fill_state(&self, t: &mut StepTrace) {
        t.state.clear();
        t.goals.clear();
        t.protected.clear();
        for (i, name) in self.conditions.iter().enumerate() {
            let c = self.count.get(i).copied().unwrap_or(0);
            for _ in 0..c.min(64) {
                t.state.push(name.clone());
            }
            if self.goal.get(i).copied().unwrap_or(false) {
                if c > 0 {
                    t.protected.push(name.clone());
                } else {
                    t.goals.push(name.clone());
                }
            }
        }
    }

    /// Whether every goal is true.
    #[must_use]
    pub fn goals_achieved(&self) -> bool {
        self.goal
            .iter()
            .enumerate()
            .all(|(i, &g)| !g || self.is_true(i))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO: &str = r#"
name = "two"
goals = ["g"]
[params]
theta = 1000.0
[[condition]]
name = "c"
initial = true
[[condition]]
name = "g"
[[module]]
name = "a"
pre = ["c"]
add = ["g"]
[[module]]
name = "b"
weight = 2.0
pre = ["c"]
add = ["g"]
"#;

    #[test]
    fn exact_normalisation_keeps_the_mean_at_pi() {
        let mut net = Network::from_toml(TWO).unwrap();
        let t = net.step();
        let sum: f64 = t.modules.iter().map(|m| m.activation).sum();
        assert!((sum - 2.0 * 20.0).abs() < 1e-9);
        assert_eq!(t.fired, None);
        assert!((t.next_threshold - 900.0).abs() < 1e-9, "θ decays by 10%");
    }

    #[test]
    fn weight_breaks_ties_and_threshold_resets() {
        let mut net = Network::from_toml(TWO).unwrap();
        let fired = (0..200).find_map(|_| net.step().fired).unwrap();
        assert_eq!(fired, "b", "equal activation: the heavier module wins");
        assert!((net.threshold() - 1000.0).abs() < 1e-9);
        assert_eq!(net.activations()[1], 0.0, "fired module is reset");
    }

    #[test]
    fn scale_down_only_shrinks() {
        let mut spec = NetworkSpec::from_toml(TWO).unwrap();
        spec.params.normalization = Normalization::ScaleDown;
        let mut net = Network::new(&spec).unwrap();
        let t = net.step();
        let sum: f64 = t.modules.iter().map(|m| m.activation).sum();
        // Each module gets φ/2 + γ/2 = 45, 90 in total > n·π = 40: scaled down to 40.
        assert!((sum - 40.0).abs() < 1e-9);
        spec.params.gamma = 1.0;
        spec.params.phi = 1.0;
        let mut net = Network::new(&spec).unwrap();
        let sum: f64 = net.step().modules.iter().map(|m| m.activation).sum();
        assert!(
            (sum - 2.0).abs() < 1e-9,
            "below n·π it is left alone: {sum}"
        );
    }

    #[test]
    fn protected_goals_take_energy_away() {
        let text = r#"
name = "p"
goals = ["g"]
[[condition]]
name = "g"
initial = true
[[condition]]
name = "c"
initial = true
[[module]]
name = "undo"
pre = ["c"]
del = ["g"]
[[module]]
name = "keep"
pre = ["c"]
"#;
        let mut spec = NetworkSpec::from_toml(text).unwrap();
        spec.params.normalization = Normalization::ScaleDown;
        let mut net = Network::new(&spec).unwrap();
        let t = net.step();
        assert_eq!(t.protected, ["g"]);
        assert!(t.modules[0].activation < t.modules[1].activation);
        assert_eq!(t.modules[0].activation, 0.0, "10 in, 50 out, clamped at 0");
    }

    #[test]
    fn spec_errors_are_typed() {
        let bad = |s: &str| Network::from_toml(s).unwrap_err();
        assert!(matches!(bad("name = 1"), SpecError::Toml(_)));
        assert_eq!(bad("name = \"x\""), SpecError::NoModules);
        assert!(matches!(
            bad("name = \"x\"\n[[module]]\nname = \"m\"\npre = [\"nope\"]"),
            SpecError::UnknownProposition { .. }
        ));
        assert_eq!(
            bad("name = \"x\"\ngoals = [\"g\"]\n[[module]]\nname = \"m\""),
            SpecError::UnknownGoal("g".into())
        );
        assert_eq!(
            bad("name = \"x\"\n[params]\ntheta = -1.0\n[[module]]\nname = \"m\""),
            SpecError::BadParam("theta")
        );
        // Absurdly large energies are refused too, with the range named.
        for (p, v) in [
            ("gamma", "1e308"),
            ("phi", "1e7"),
            ("pi", "inf"),
            ("delta", "-1"),
        ] {
            let e = bad(&format!(
                "name = \"x\"\n[params]\n{p} = {v}\n[[module]]\nname = \"m\""
            ));
            assert!(
                matches!(e, SpecError::BadParam(n) if n == p),
                "{p} = {v}: {e:?}"
            );
            assert!(e.to_string().contains("1000000"), "{e}");
        }
        assert_eq!(
            bad(
                "name = \"x\"\n[[condition]]\nname = \"c\"\n[[condition]]\nname = \"c\"\n[[module]]\nname = \"m\""
            ),
            SpecError::DuplicateCondition("c".into())
        );
        assert!(matches!(
            bad("name = \"x\"\ntypo = 1\n[[module]]\nname = \"m\""),
            SpecError::Toml(_)
        ));
        // Names nothing could refer to.
        assert_eq!(
            bad("name = \"x\"\n[[module]]\nname = \" \""),
            SpecError::EmptyName("module")
        );
        let e = bad("name = \"x\"\n[[condition]]\nname = \"\"\n[[module]]\nname = \"m\"");
        assert_eq!(e, SpecError::EmptyName("condition"));
        assert_eq!(e.to_string(), "a condition has an empty name");
    }

    /// A wrong initial value says what is allowed (it said "data did not match any variant
    /// of untagged enum Initial").
    #[test]
    fn a_wrong_initial_value_says_what_is_allowed() {
        let spec = |v: &str| {
            format!(
                "name = \"m\"\n[[condition]]\nname = \"h\"\ninitial = {v}\n[[module]]\nname = \"x\""
            )
        };
        for v in ["-5", "2.5", "99999999999", "\"yes\""] {
            let e = Network::from_toml(&spec(v)).unwrap_err().to_string();
            assert!(
                e.contains("expected true, false, or a count from 0 to 4294967295"),
                "{v}: {e}"
            );
        }
        for (v, want) in [("7", Initial::Count(7)), ("true", Initial::Flag(true))] {
            let s: spec::NetworkSpec = toml::from_str(&spec(v)).unwrap();
            assert_eq!(s.conditions[0].initial, want, "{v}");
        }
    }

    #[test]
    fn multiset_state() {
        let text = "name = \"m\"\n[[condition]]\nname = \"h\"\ninitial = 2\n[[condition]]\nname = \"f\"\ninitial = true\n[[module]]\nname = \"x\"\npre = [\"h\"]\ndel = [\"h\"]\nadd = [\"f\"]";
        let mut net = Network::from_toml(text).unwrap();
        assert!(net.apply_effects("x"));
        assert_eq!(net.condition("h"), Some(true), "one hand left");
        assert!(net.apply_effects("x"));
        assert_eq!(net.condition("h"), Some(false));
        net.set_state(&["f", "f", "h", "h", "h"]).unwrap();
        let t = net.step();
        assert_eq!(t.state, ["h", "h", "h", "f"], "flags cap at one instance");
        assert!(!net.apply_effects("nope"));
    }
}
