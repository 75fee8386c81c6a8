//! No input may panic the front end: arbitrary bytes, and real robot descriptions with
//! random edits (deleted or repeated spans, numbers replaced by hostile tokens). When an
//! edited robot still loads, the summary and the reference dynamics must run too.

use grid_gen::{info::Info, reference, Model};
use proptest::prelude::*;

fn robots_text() -> Vec<String> {
    grid_gen_test_support::robots()
        .iter()
        .map(|r| {
            std::fs::read_to_string(
                grid_gen_test_support::repo().join("robots").join(format!("{r}.urdf")),
            )
            .unwrap()
        })
        .collect()
}

/// Loads and, if that succeeds, exercises everything downstream of the model.
fn exercise(text: &str) {
    match Model::from_urdf_str("fuzz.urdf", text, false) {
        Ok((model, _)) => {
            let _ = Info::new(&model).to_text();
            // q has nq entries (a floating base or spherical joint stores a quaternion),
            // velocities and accelerations nv: an edit can turn the root floating.
            let n = model.nv();
            let q = vec![0.3; model.nq()];
            let v = vec![0.3; n];
            let _ = reference::rnea_derivatives(&model, &q, &v, &v, reference::DEFAULT_GRAVITY);
            let _ = reference::forward_dynamics_derivatives(
                &model,
                &q,
                &v,
                &v,
                reference::DEFAULT_GRAVITY,
            );
            // Generation too (small robots only, to keep the test quick): an error is
            // fine, a panic is not.
            if n <= 7 {
                if let Ok(files) =
                    grid_gen::generate::generate(&model, &grid_gen::generate::Options::default())
                {
                    assert!(files
                        .iter()
                        .all(|f| !f.name.contains(['/', '\\']) && f.name.ends_with(".rs")));
                }
            }
        }
        Err(e) => {
            assert!(!e.diagnostics.is_empty(), "a failure carries at least one diagnostic");
            let _ = e.render_plain();
        }
    }
}

const TOKENS: &[&str] = &[
    "", "nan", "inf", "-1", "0", "1e308", "-1e-320", "x", "1 2", "\"", "<", "&amp;", "fixed",
    "floating", "base", "1 0 0 0",
];

#[derive(Debug, Clone)]
enum Edit {
    Delete(usize, usize),
    Repeat(usize, usize),
    Token(usize, usize),
}

fn apply(text: &str, edits: &[Edit]) -> String {
    let mut s = text.as_bytes().to_vec();
    for e in edits {
        let len = s.len().max(1);
        match *e {
            Edit::Delete(at, n) => {
                let a = at % len;
                let b = (a + n % 64).min(s.len());
                s.drain(a..b);
            }
            Edit::Repeat(at, n) => {
                let a = at % len;
                let b = (a + n % 400).min(s.len());
                let piece = s[a..b].to_vec();
                s.splice(b..b, piece);
            }
            Edit::Token(at, t) => {
                // Replace the quoted value that contains `at` with a hostile token.
                let a = at % len;
                let Some(open) = s[..a].iter().rposition(|&c| c == b'"') else { continue };
                let Some(close) = s[a..].iter().position(|&c| c == b'"') else { continue };
                s.splice(open + 1..a + close, TOKENS[t % TOKENS.len()].bytes());
            }
        }
    }
    String::from_utf8_lossy(&s).into_owned()
}

/// `cases` random cases, or `PROPTEST_CASES` of them (for a long local fuzzing run). The
/// seed is random on a developer's machine (each run explores new edits) and fixed under CI
/// (a landing gate must not depend on a draw; the seed advances only by hand), unless
/// `PROPTEST_RNG_SEED` names one: a failure found locally is replayed with the same seed.
fn fuzz_config(cases: u32) -> ProptestConfig {
    let from_env = ProptestConfig::default();
    let set = |var: &str| std::env::var_os(var).is_some();
    ProptestConfig {
        cases: if set("PROPTEST_CASES") { from_env.cases } else { cases },
        rng_seed: if !set("PROPTEST_RNG_SEED") && set("CI") {
            proptest::test_runner::RngSeed::Fixed(20261124)
        } else {
            from_env.rng_seed
        },
        failure_persistence: None,
        ..from_env
    }
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<usize>(), any::<usize>()).prop_map(|(a, n)| Edit::Delete(a, n)),
        (any::<usize>(), any::<usize>()).prop_map(|(a, n)| Edit::Repeat(a, n)),
        (any::<usize>(), any::<usize>()).prop_map(|(a, t)| Edit::Token(a, t)),
    ]
}

proptest! {
    #![proptest_config(fuzz_config(512))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        exercise(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn mutated_robots_never_panic(robot in 0usize..64, edits in proptest::collection::vec(edit(), 1..6)) {
        let texts = robots_text();
        exercise(&apply(&texts[robot % texts.len()], &edits));
    }
}

fn scenes_text() -> Vec<(String, String)> {
    ["grid_iiwa/iiwa_wrist_locked", "grid_hyq/hyq_front_legs", "grid_hyq/hyq_knees_locked"]
        .iter()
        .map(|rs| {
            let (robot, scene) = rs.split_once('/').unwrap();
            let root = grid_gen_test_support::repo();
            (
                std::fs::read_to_string(root.join("robots").join(format!("{robot}.urdf"))).unwrap(),
                std::fs::read_to_string(root.join("examples/scenes").join(format!("{scene}.toml")))
                    .unwrap(),
            )
        })
        .collect()
}

proptest! {
    #![proptest_config(fuzz_config(256))]

    /// A scene file with random edits is read, refused with a message, or applied; when it
    /// applies, the summary and the reference dynamics of the reduced robot run.
    #[test]
    fn mutated_scenes_never_panic(which in 0usize..3, edits in proptest::collection::vec(edit(), 1..6)) {
        let (urdf, scene) = &scenes_text()[which];
        let text = apply(scene, &edits);
        match grid_gen::Scene::parse("fuzz.toml", &text) {
            Err(e) => prop_assert!(e.to_string().starts_with("scene `fuzz.toml`: ")),
            Ok(parsed) => match Model::from_urdf_str_in_scene("robot.urdf", urdf, false, &parsed, "fuzz.toml") {
                Ok((model, _)) => {
                    let _ = Info::new(&model).to_text();
                    let q = vec![0.3; model.nq()];
                    let v = vec![0.3; model.nv()];
                    let _ = reference::rnea_derivatives(&model, &q, &v, &v, parsed.gravity.unwrap_or(reference::DEFAULT_GRAVITY));
                }
                Err(e) => prop_assert!(!e.diagnostics.is_empty()),
            },
        }
    }
}

#[test]
fn overflowing_numbers_are_an_error_not_a_literal() {
    let text = r#"<robot name="big"><link name="base"/>
      <link name="a"><inertial><origin xyz="1e200 0 0"/><mass value="1e300"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
      <joint name="j" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/></joint></robot>"#;
    let (model, _) = Model::from_urdf_str("big.urdf", text, false).unwrap();
    let err = grid_gen::generate::generate(&model, &grid_gen::generate::Options::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("overflows f64"), "{err}");
}

#[test]
fn deep_chains_do_not_overflow_the_stack() {
    let mut s = String::from("<robot name=\"chain\"><link name=\"l0\"/>");
    for i in 1..=20_000 {
        s.push_str(&format!(
            "<link name=\"l{i}\"><inertial><mass value=\"1\"/><inertia ixx=\"1\" ixy=\"0\" ixz=\"0\" iyy=\"1\" iyz=\"0\" izz=\"1\"/></inertial></link>\
             <joint name=\"j{i}\" type=\"fixed\"><parent link=\"l{}\"/><child link=\"l{i}\"/></joint>",
            i - 1
        ));
    }
    s.push_str("</robot>");
    let (model, _) = Model::from_urdf_str("chain.urdf", &s, false).unwrap();
    assert_eq!(model.nv(), 0);
}

/// The edit CI's random draw found on 2026-11-24: a robot whose fixed root joint is turned
/// floating has nq = nv + 1 positions, and the exercise must pass q with nq entries.
#[test]
fn a_robot_edited_to_float_is_exercised_with_its_quaternion() {
    let text = robots_text()
        .into_iter()
        .find(|t| t.contains(r#"<robot name="iiwa"#) || t.contains("iiwa_base_joint"))
        .unwrap();
    let edited = text.replacen(
        r#"name="iiwa_base_joint" type="fixed""#,
        r#"name="iiwa_base_joint" type="floating""#,
        1,
    );
    assert_ne!(edited, text, "the edit applies");
    let (model, _) = Model::from_urdf_str("fuzz.urdf", &edited, false).unwrap();
    assert_eq!(model.nq(), model.nv() + 1, "a free-flyer root");
    exercise(&edited);
}
