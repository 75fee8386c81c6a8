//! What a new user tripped over, each answered by a message that says what to do: a
//! top-level scene key after a table, a states file that is a bare array, a velocity of
//! the wrong length on a floating base, a xacro file.

use grid_gen::eval::{check_states, parse_states};
use grid_gen::{Model, Scene};
use grid_gen_test_support::*;

#[test]
fn a_top_level_scene_key_after_a_table_says_to_move_it() {
    let e = Scene::parse("s.toml", "[lock]\niiwa_joint_7 = 0.0\n\nstatic = true\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("line 4: `static` is a top-level key, but it comes after `[lock]`")
            && e.contains("move it above the first [table]"),
        "{e}"
    );
    // Before the table, the same keys parse.
    assert!(
        Scene::parse("s.toml", "static = true\n[lock]\niiwa_joint_7 = 0.0\n")
            .unwrap()
            .static_velocity
    );
}

#[test]
fn a_bare_array_of_states_says_to_wrap_it() {
    let e = parse_states(r#"[{"q": [0.0], "qd": [0.0]}]"#).unwrap_err().to_string();
    assert!(
        e.contains("bare array") && e.contains(r#"{"states": [{"q": [...], "qd": [...]}, ...]}"#),
        "{e}"
    );
}

#[test]
fn a_floating_velocity_of_the_wrong_length_counts_velocity_coordinates() {
    let model = load_floating("grid_hyq");
    let q = model.neutral_q();
    let file =
        parse_states(&format!(r#"{{"states": [{{"q": {q:?}, "qd": {:?}}}]}}"#, vec![0.0; 12]))
            .unwrap();
    let e = check_states(&model, &file).unwrap_err().to_string();
    assert!(e.contains("`qd` has 12 entries, the robot has 18 velocity coordinates (nv: the floating base's six, then one per joint)"), "{e}");
}

#[test]
fn a_xacro_file_says_to_expand_it() {
    let text = r#"<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:include filename="arm.xacro"/></robot>"#;
    let e = Model::from_urdf_str("robot.urdf.xacro", text, false).unwrap_err().render_plain();
    assert!(
        e.contains("robot.urdf.xacro is a xacro file")
            && e.contains("xacro robot.urdf.xacro > robot.urdf"),
        "{e}"
    );
}
