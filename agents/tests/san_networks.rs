//! The shipped networks parse, and their behaviour is pinned.

use ima_agents::san::Network;

fn load(name: &str) -> Network {
    let path = format!("{}/networks/{name}", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).unwrap();
    Network::from_toml(&text).unwrap()
}

/// (step, module) for every firing in `steps` simulated steps.
fn firings(net: &mut Network, steps: usize) -> Vec<(u64, String)> {
    (0..steps)
        .filter_map(|_| {
            let t = net.simulate_step();
            t.fired.map(|f| (t.step, f))
        })
        .collect()
}

fn scenario(file: &str, state: &[&str], steps: usize) -> Vec<(u64, String)> {
    let mut net = load(file);
    net.set_state(state).unwrap();
    let f = firings(&mut net, steps);
    println!("{file} {state:?}: {f:?}");
    f
}

#[test]
fn all_shipped_networks_parse() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/networks");
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "toml") {
            Network::from_toml(&std::fs::read_to_string(&p).unwrap())
                .unwrap_or_else(|err| panic!("{}: {err}", p.display()));
            n += 1;
        }
    }
    assert!(n >= 3);
}

#[test]
fn maes_toy_sequence() {
    let mut net = load("maes_toy.toml");
    let seq = firings(&mut net, 20);
    let want = [
        (3, "pick-up-sander"),
        (5, "pick-up-board"),
        (7, "sand-board-in-hand"),
        (18, "place-board-in-vise"),
        (19, "pick-up-sprayer"),
        (20, "spray-paint-self"),
    ];
    let want: Vec<(u64, String)> = want.iter().map(|&(s, m)| (s, m.to_owned())).collect();
    assert_eq!(seq, want);
    // Sanding before painting: painting deletes `operational`, which sanding needs.
    assert!(net.goals_achieved());
}

fn pinned(file: &str, state: &[&str], steps: usize, want: &[(u64, &str)]) {
    let got = scenario(file, state, steps);
    let want: Vec<(u64, String)> = want.iter().map(|&(s, m)| (s, m.to_owned())).collect();
    assert_eq!(got, want);
}

#[test]
fn skeeter_asks_scooter_then_reports_failure() {
    pinned(
        "skeeter.toml",
        &[
            "target-requested",
            "scooter-in-view",
            "target-not-in-view",
            "scooter-cannot-see-target",
        ],
        18,
        &[
            (6, "scan-for-target"),
            (12, "ask-scooter"),
            (18, "report-failed"),
        ],
    );
}

#[test]
fn skeeter_sends_a_requested_heading_at_once() {
    pinned(
        "skeeter.toml",
        &[
            "target-requested",
            "scan-done",
            "target-in-view",
            "scooter-in-view",
            "heading-requested",
        ],
        1,
        &[(1, "send-heading")],
    );
}

#[test]
fn skeeter_calls_scooter_back_before_sending_a_heading() {
    pinned(
        "skeeter.toml",
        &[
            "target-requested",
            "scan-done",
            "target-in-view",
            "scooter-lost",
            "heading-requested",
        ],
        4,
        &[(3, "call-back-scooter"), (4, "send-heading")],
    );
}

#[test]
fn skeeter_reports_success_and_timeout() {
    let base = [
        "target-requested",
        "scan-done",
        "target-in-view",
        "scooter-in-view",
    ];
    let mut s = base.to_vec();
    s.push("scooter-reached-target");
    pinned("skeeter.toml", &s, 6, &[(6, "report-accomplished")]);
    let mut s = base.to_vec();
    s.push("timeout");
    pinned("skeeter.toml", &s, 6, &[(6, "report-timeout")]);
}

#[test]
fn scooter_requests_a_heading_follows_it_and_notifies() {
    pinned(
        "scooter.toml",
        &["heading-stale", "path-clear", "skeeter-in-view"],
        20,
        &[
            (9, "request-heading"),
            (16, "follow-heading"),
            (19, "move-to-target"),
            (20, "notify-skeeter"),
        ],
    );
}

#[test]
fn scooter_avoids_then_resumes() {
    pinned(
        "scooter.toml",
        &["obstacle-near", "target-in-view", "skeeter-in-view"],
        10,
        &[
            (6, "avoid-obstacle"),
            (9, "move-to-target"),
            (10, "notify-skeeter"),
        ],
    );
}

#[test]
fn scooter_goes_home_when_called_and_answers_questions() {
    pinned(
        "scooter.toml",
        &["called-back", "path-clear", "heading-known"],
        1,
        &[(1, "move-to-home")],
    );
    pinned(
        "scooter.toml",
        &[
            "asked-for-target",
            "path-clear",
            "skeeter-in-view",
            "heading-known",
        ],
        1,
        &[(1, "reply-target-query")],
    );
}

#[test]
fn conditions_fed_by_agents_drive_the_choice() {
    // Live use: no simulated effects; an agent reports the world through set_condition.
    let mut net = load("scooter.toml");
    net.set_state(&["target-in-view", "path-clear", "skeeter-in-view"])
        .unwrap();
    let first = (0..10).find_map(|_| net.step().fired).unwrap();
    assert_eq!(first, "move-to-target");
    net.set_condition("path-clear", false).unwrap();
    net.set_condition("obstacle-near", true).unwrap();
    let next = (0..10).find_map(|_| net.step().fired).unwrap();
    assert_eq!(next, "avoid-obstacle");
    assert!(net.set_condition("no-such", true).is_err());
}

#[test]
fn traces_are_deterministic() {
    let run = || {
        let mut net = load("maes_toy.toml");
        (0..30).map(|_| net.simulate_step()).collect::<Vec<_>>()
    };
    assert_eq!(run(), run());
}
