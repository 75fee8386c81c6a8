//! A scene's `round_angles`: `<origin rpy>` angles written to fewer digits than an f64
//! holds (HyQ's `1.57079632679`, Atlas's single-precision `1.5707963705062866`) read as
//! the multiple of π/2 they stand for.
//!
//! Why it matters: a rotation by exactly a multiple of π/2 is a signed permutation, and
//! the kernels apply it as one (model constants within `ir::SNAP` of 0 and ±1 are exact);
//! `1.57079632679` is 4.9e-12 rad short of π/2, so its rotation has entries of 4.9e-12
//! where π/2's has zeros, and every transform through that joint costs its dense price.
//! Reading it as π/2 changes the robot by that angle: the results move from Pinocchio's
//! on the literal file by about that much, relative. Off unless a scene asks.

use super::Urdf;

/// The largest tolerance a scene may give: an angle written in single precision is
/// within 1.2e-7 rad (half an f32 ulp at π) of the value meant; more than this would
/// change a robot's geometry, not its round-off.
pub const MAX_ROUND_ANGLES: f64 = 1e-6;

/// What [`round_angles`] changed.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RoundedAngles {
    /// The scene's tolerance, rad.
    pub tolerance: f64,
    /// How many angles moved (angles already exact are not counted).
    pub count: usize,
    /// The largest change, rad.
    pub largest: f64,
}

/// `round_angles = TOL read N <origin rpy> angles as multiples of pi/2 (largest change X
/// rad)`: what `info` and the generated files' headers say of it.
impl std::fmt::Display for RoundedAngles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "round_angles = {:e} read {} <origin rpy> angles as multiples of pi/2 (largest change {:.2e} rad)",
            self.tolerance, self.count, self.largest
        )
    }
}

/// The multiple of π/2 within `tolerance` of `angle`, if any.
fn rounded(angle: f64, tolerance: f64) -> Option<f64> {
    let k = (angle / std::f64::consts::FRAC_PI_2).round();
    let exact = k * std::f64::consts::FRAC_PI_2;
    ((angle - exact).abs() <= tolerance).then_some(exact)
}

/// Reads every joint's and inertial's `<origin rpy>` angle within `tolerance` of a
/// multiple of π/2 as that multiple. `tolerance` must be in `(0, MAX_ROUND_ANGLES]`
/// (the scene checks it).
pub fn round_angles(urdf: &mut Urdf, tolerance: f64) -> RoundedAngles {
    let mut report = RoundedAngles { tolerance, ..RoundedAngles::default() };
    let joints = urdf.joints.iter_mut().map(|j| &mut j.origin);
    let inertials =
        urdf.links.iter_mut().filter_map(|l| l.inertial.as_mut().map(|i| &mut i.origin));
    for pose in joints.chain(inertials) {
        for a in &mut pose.rpy {
            if let Some(exact) = rounded(*a, tolerance) {
                if exact != *a {
                    report.count += 1;
                    report.largest = report.largest.max((exact - *a).abs());
                    *a = exact;
                }
            }
        }
    }
    report
}

#[cfg(test)]
#[allow(clippy::approx_constant)] // truncated multiples of π/2 are the point
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    #[test]
    fn truncated_right_angles_become_exact_and_others_stay() {
        // HyQ's URDF (robots/grid_hyq.urdf) and Atlas's (single precision).
        assert_eq!(rounded(1.57079632679, 1e-11), Some(FRAC_PI_2));
        assert_eq!(rounded(-3.1415926535895866, 1e-11), Some(-PI));
        assert_eq!(rounded(1.5707963705062866, 1e-11), None);
        assert_eq!(rounded(1.5707963705062866, 1e-7), Some(FRAC_PI_2));
        assert_eq!(rounded(-2.3561944901923457, 1e-7), None);
        assert_eq!(rounded(1e-12, 1e-11), Some(0.0));
        assert_eq!(rounded(0.3, 1e-6), None);
    }

    #[test]
    fn counts_what_moved() {
        let text = r#"<robot name="r">
  <link name="a"><inertial><origin rpy="0 1.57079632679 0"/><mass value="1"/>
    <inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="b"><inertial><mass value="1"/>
    <inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <joint name="j" type="revolute"><parent link="a"/><child link="b"/>
    <origin rpy="1.57079632679 0.25 3.141592653589793"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"#;
        let (mut urdf, _, _) = crate::urdf::load("r.urdf", text).unwrap();
        let report = round_angles(&mut urdf, 1e-11);
        assert_eq!(report.count, 2);
        assert_eq!(report.largest, FRAC_PI_2 - 1.57079632679);
        assert_eq!(urdf.joints[0].origin.rpy, [FRAC_PI_2, 0.25, PI]);
        assert_eq!(urdf.links[0].inertial.as_ref().unwrap().origin.rpy, [0.0, FRAC_PI_2, 0.0]);
    }
}
