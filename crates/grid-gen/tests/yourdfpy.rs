//! The parsed tree against an independent parser, yourdfpy (tests/fixtures/*.yourdfpy.json):
//! joint names, types, parents, children, origins and axes as read, and the pose of every
//! moving body at random configurations (which checks fixed-joint merging and the model's
//! tree transforms). Tolerance 1e-12 absolute on unit rotations and metre-scale
//! positions: both sides compose a handful of f64 rotations.

use grid_gen::{reference, spatial::rpy_matrix};
use grid_gen_test_support::*;

const TOL: f64 = 1e-12;

#[test]
fn parsed_tree_matches_yourdfpy() {
    for robot in robots() {
        let path = repo().join("robots").join(format!("{robot}.urdf"));
        let text = std::fs::read_to_string(&path).unwrap();
        let (urdf, _, _) = grid_gen::urdf::load(&robot, &text).unwrap();
        let fx = fixture(&format!("{robot}.yourdfpy.json"));
        assert_eq!(fx["robot"].as_str().unwrap(), urdf.name, "{robot}: robot name");
        let joints = fx["joints"].as_array().unwrap();
        assert_eq!(joints.len(), urdf.joints.len(), "{robot}: joint count");
        for (theirs, ours) in joints.iter().zip(&urdf.joints) {
            let name = &ours.name;
            assert_eq!(theirs["name"].as_str().unwrap(), name);
            assert_eq!(
                theirs["type"].as_str().unwrap(),
                ours.kind.as_str(),
                "{robot}/{name}: type"
            );
            assert_eq!(theirs["parent"].as_str().unwrap(), ours.parent, "{robot}/{name}: parent");
            assert_eq!(theirs["child"].as_str().unwrap(), ours.child, "{robot}/{name}: child");
            let origin = mat_of(&theirs["origin"]);
            let r = rpy_matrix(ours.origin.rpy);
            for i in 0..3 {
                assert!(
                    (origin[(i, 3)] - ours.origin.xyz[i]).abs() <= TOL,
                    "{robot}/{name}: origin xyz"
                );
                for j in 0..3 {
                    assert!(
                        (origin[(i, j)] - r[(i, j)]).abs() <= TOL,
                        "{robot}/{name}: origin rotation"
                    );
                }
            }
            if ours.kind != grid_gen::urdf::JointKind::Fixed {
                assert_eq!(vec_of(&theirs["axis"]), ours.axis.to_vec(), "{robot}/{name}: axis");
            }
        }
    }
}

#[test]
fn body_poses_match_yourdfpy() {
    for robot in robots() {
        let model = load(&robot);
        let path = repo().join("robots").join(format!("{robot}.urdf"));
        let text = std::fs::read_to_string(&path).unwrap();
        let (urdf, _, _) = grid_gen::urdf::load(&robot, &text).unwrap();
        let fx = fixture(&format!("{robot}.yourdfpy.json"));
        assert_eq!(fx["base_link"].as_str().unwrap(), model.root_link, "{robot}: root link");
        for cfg in fx["configurations"].as_array().unwrap() {
            let given = cfg["q"].as_object().unwrap();
            let mut q: Vec<f64> = model
                .joints
                .iter()
                .map(|j| given.get(&j.name).and_then(|v| v.as_f64()).unwrap_or(f64::NAN))
                .collect();
            // yourdfpy drives mimic joints from the joint they follow.
            for (i, j) in model.joints.iter().enumerate() {
                if let Some((m, mult, off)) = &j.mimic {
                    q[i] = mult * given[m.as_str()].as_f64().unwrap() + off;
                }
            }
            assert!(q.iter().all(|x| x.is_finite()), "{robot}: every joint configured");
            let poses = reference::forward_kinematics(&model, &q);
            for (i, joint) in model.joints.iter().enumerate() {
                let child = &urdf.joints.iter().find(|j| j.name == joint.name).unwrap().child;
                let want = mat_of(&cfg["link_poses"][child.as_str()]);
                let (r, p) = &poses[i];
                for a in 0..3 {
                    assert!(
                        (want[(a, 3)] - p[a]).abs() <= TOL,
                        "{robot}/{child}: position {p:?} vs {want}"
                    );
                    for b in 0..3 {
                        assert!(
                            (want[(a, b)] - r[(a, b)]).abs() <= TOL,
                            "{robot}/{child}: rotation"
                        );
                    }
                }
            }
        }
    }
}
