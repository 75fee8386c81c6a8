//! Contacts stabilised as Pinocchio's Baumgarte corrector (`baumgarte = true`): the contact
//! kernels and the step take `gains` (Kp, Kd per contact) and `contact_ref` (a point's world
//! position, a wrench's world placement), and drive each contact's acceleration to
//! `−Kd v − Kp e` (e a point's `p − p_ref`, a wrench's `−log6(oMc⁻¹ oMref)` in world axes). The IR's
//! derivatives come from forward-mode differentiation of the corrected accelerations; the
//! reference's are written by hand (`reference/contact.rs`), and its values are checked
//! against `pin.constraintDynamics` with the corrector set in `python/tests`.

use grid_gen::ir::{self, Input, KernelKind, LowerOptions};
use grid_gen::model::{ContactKind, Scheme};
use grid_gen::{reference, Model};
use grid_gen_test_support::*;

/// Floating HyQ on its four lower legs as point contacts, stabilised, a force on its base.
fn stabilised_hyq() -> Model {
    let legs = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
        .map(|l| (l, ContactKind::Point));
    let mut m = with_forces(&load_floating("grid_hyq"), &["root_joint"], &legs);
    m.specialisation.baumgarte = true;
    m
}

/// The reference's outputs of a contact or step kernel of `m` under the corrector `corr`,
/// in the kernel's output order.
#[allow(clippy::too_many_arguments)]
fn corrected_reference(
    kind: KernelKind,
    m: &Model,
    q: &[f64],
    qd: &[f64],
    u: &[f64],
    fext: &[f64],
    dt: f64,
    corr: reference::Baumgarte,
) -> Vec<nalgebra::DMatrix<f64>> {
    let g = reference::DEFAULT_GRAVITY;
    match kind {
        KernelKind::ContactFd | KernelKind::ContactFdGrad => {
            let (sol, d) =
                reference::contact_fd_derivatives_with(m, q, qd, u, g, fext, corr).unwrap();
            let mut out = vec![col(&sol.qdd), col(&sol.lambda)];
            if kind == KernelKind::ContactFdGrad {
                out.extend([d.dqdd_dq, d.dqdd_dqd, d.dqdd_dtau]);
                out.extend([d.dlambda_dq, d.dlambda_dqd, d.dlambda_dtau]);
            }
            out
        }
        KernelKind::Step | KernelKind::StepGrad => {
            let step = m.specialisation.step.unwrap().at(dt);
            let tau = actuated_tau(m, u);
            let (lam, dx, du) =
                reference::step_lambda_with(m, q, qd, &tau, g, &m.actuated(), fext, corr).unwrap();
            if kind == KernelKind::Step {
                let (q1, v1) = reference::step_with(m, q, qd, &tau, g, step, fext, corr).unwrap();
                return vec![col(&q1), col(&v1), col(&lam)];
            }
            let d = reference::step_derivatives_with(
                m,
                q,
                qd,
                &tau,
                g,
                step,
                &m.actuated(),
                fext,
                corr,
            )
            .unwrap();
            vec![
                col(&d.q_next),
                col(&d.qd_next),
                d.a,
                d.b,
                col(&lam),
                dx,
                col(du.transpose().as_slice()),
            ]
        }
        _ => unreachable!("{kind} takes no gains"),
    }
}

/// `contact_fd`, `contact_fd_grad` and the semi-implicit `step`, `step_grad` of stabilised
/// floating HyQ against the reference on random states, gains and references (feet up to
/// 5 cm from their references, as a drifting plan's), with fext on the base.
#[test]
fn stabilised_contacts_match_the_reference() {
    let worst = check_stabilised(&stabilised_hyq(), 101, 0.0);
    println!("stabilised floating HyQ: worst {worst:.2e} from the reference (bound 1e-12)");
}

/// Wrench contacts, whose error is SE(3)'s logarithm: floating HyQ with its left front foot
/// held as a wrench and its right hind foot as a point, and iiwa's flange as a wrench, each
/// with references turned by up to 0.5 rad and by 3.1 rad (near the half turn where the
/// logarithm's axis comes from the quaternion's vector part alone).
#[test]
fn stabilised_wrench_contacts_match_the_reference() {
    let feet = [("lf_lowerleg", ContactKind::Wrench), ("rh_lowerleg", ContactKind::Point)];
    let mut hyq = with_forces(&load_floating("grid_hyq"), &["root_joint"], &feet);
    hyq.specialisation.baumgarte = true;
    let mut iiwa = with_forces(&load("grid_iiwa"), &[], &[("iiwa_link_7", ContactKind::Wrench)]);
    iiwa.specialisation.baumgarte = true;
    let mut worst: f64 = 0.0;
    for (seed, angle) in [(111, 0.5), (113, 3.1)] {
        worst = worst.max(check_stabilised(&hyq, seed, angle));
        worst = worst.max(check_stabilised(&iiwa, seed + 1, angle));
    }
    println!("stabilised wrench contacts: worst {worst:.2e} from the reference (bound 1e-12)");
}

/// Every contact and step kernel of the stabilised model `m` (fext on its first joint, if
/// it takes any) against the reference at three random states: gains Kp in [0, 200], Kd in
/// [0, 30], each reference 5 cm from its contact and, for a wrench, turned by a random
/// rotation of `angle` rad. Returns the worst relative error.
fn check_stabilised(m: &Model, seed: u64, angle: f64) -> f64 {
    let m = with_step(m, Scheme::SemiImplicitEuler, 0.01);
    let g = reference::DEFAULT_GRAVITY;
    let kernels = vec![
        KernelKind::ContactFd,
        KernelKind::ContactFdGrad,
        KernelKind::Step,
        KernelKind::StepGrad,
    ];
    let module = ir::lower(&m, g, &LowerOptions { kernels, ..LowerOptions::default() }).unwrap();
    let mut rng = Rng(seed);
    let (nv, nc) = (m.nv(), m.specialisation.contacts.len());
    let mut worst: f64 = 0.0;
    for f in &module.functions {
        let n = f.inputs().len();
        assert_eq!(&f.inputs()[n - 2..], &[Input::Gains, Input::ContactRef], "{}", f.kind);
    }
    for _ in 0..3 {
        let q = m.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
        let (qd, fext) = (rng.vec(nv, -2.0, 2.0), rng.vec(6 * m.nfext(), -20.0, 20.0));
        let ext = reference::External { fext: &fext, lambda: &[] };
        let gains: Vec<f64> =
            (0..nc).flat_map(|_| [rng.vec(1, 0.0, 200.0)[0], rng.vec(1, 0.0, 30.0)[0]]).collect();
        let refs = contact_refs(&m, &q, &mut rng, angle);
        let corr = reference::Baumgarte { gains: &gains, refs: &refs };
        for f in &module.functions {
            let u = if f.kind.is_step() {
                rng.vec(m.nu(), -10.0, 10.0)
            } else {
                rng.vec(nv, -10.0, 10.0)
            };
            let args = kernel_args_corrected(f.inputs(), &q, &qd, &u, ext, &[], &[], corr);
            let got = f.eval(&args);
            let want = corrected_reference(f.kind, &m, &q, &qd, &u, &fext, 0.01, corr);
            assert_eq!(got.len(), want.len(), "{}: outputs", f.kind);
            for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                let e = rel_err(&output_matrix(o.shape, nv, got), want);
                worst = worst.max(e);
                // f64 round-off through the contacts' Schur complement, as every contact
                // test (the unstabilised kernels measure ~1e-14 here).
                assert!(e < 1e-12, "{} {} {}: {e:.2e}", m.name, f.kind, o.name);
            }
        }
    }
    worst
}

/// Each contact's reference near where it is at q: its position moved by up to 5 cm, and a
/// wrench's orientation (as `[qx, qy, qz, qw]`) turned by `angle` rad about a random axis.
fn contact_refs(m: &Model, q: &[f64], rng: &mut Rng, angle: f64) -> Vec<f64> {
    let mut out = Vec::new();
    for c in &m.specialisation.contacts {
        let (r, p) = reference::frame_placement(m, q, &m.frames[c.frame]);
        out.extend(p.iter().map(|x| x + rng.vec(1, -0.05, 0.05)[0]));
        if c.kind == ContactKind::Wrench {
            let axis = nalgebra::Vector3::from_vec(rng.vec(3, -1.0, 1.0)).normalize();
            let turn = nalgebra::UnitQuaternion::from_scaled_axis(axis * angle);
            let here = nalgebra::UnitQuaternion::from_rotation_matrix(
                &nalgebra::Rotation3::from_matrix_unchecked(r),
            );
            out.extend((turn * here).quaternion().coords.iter());
        }
    }
    out
}

/// Gains 0 are the rigid contact, bit for bit: the stabilised kernels' values with zero
/// gains equal the unstabilised kernels' (the corrector adds `0 · v + 0 · e`), and the
/// corrector costs a few operations per contact.
#[test]
fn zero_gains_are_the_rigid_contact() {
    let stabilised = stabilised_hyq();
    let mut rigid = stabilised.clone();
    rigid.specialisation.baumgarte = false;
    let g = reference::DEFAULT_GRAVITY;
    let options = LowerOptions {
        kernels: vec![KernelKind::ContactFd, KernelKind::ContactFdGrad],
        ..LowerOptions::default()
    };
    let (a, b) =
        (ir::lower(&stabilised, g, &options).unwrap(), ir::lower(&rigid, g, &options).unwrap());
    let mut rng = Rng(103);
    let nv = rigid.nv();
    let q = rigid.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
    let (qd, u, fext) = (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -10.0, 10.0), rng.vec(6, -20.0, 20.0));
    let ext = reference::External { fext: &fext, lambda: &[] };
    let refs = rng.vec(12, -1.0, 1.0);
    let corr = reference::Baumgarte { gains: &[0.0; 8], refs: &refs };
    for (f, fixed) in a.functions.iter().zip(&b.functions) {
        let got = f.eval(&kernel_args_corrected(f.inputs(), &q, &qd, &u, ext, &[], &[], corr));
        let want = fixed.eval(&kernel_args_with(fixed.inputs(), &q, &qd, &u, ext));
        assert_eq!(got, want, "{}", f.kind);
        let ops = |f: &ir::Function| {
            (0..f.nodes.len()).filter(|&i| f.is_operation(ir::Id(i as u32))).count()
        };
        println!("floating HyQ {}: {} operations stabilised, {} rigid", f.kind, ops(f), ops(fixed));
    }
}

/// `baumgarte` without contacts is an error that says why; a wrench contact takes gains
/// and a 7-entry reference.
#[test]
fn baumgarte_needs_contacts() {
    let urdf = repo().join("robots/grid_iiwa.urdf");
    let mut config = grid_gen::Config::new(&urdf);
    config.overrides.baumgarte = Some(true);
    let e = config.load().unwrap_err().to_string();
    // A Config's overrides are the library's: named by the Builder method that sets them.
    assert!(e.contains("Builder::baumgarte without contacts"), "{e}");
    config.overrides.contacts = Some(vec![grid_gen::ContactEntry {
        frame: "iiwa_link_7".into(),
        kind: ContactKind::Wrench,
    }]);
    let spec = config.load().unwrap().model.specialisation;
    assert!(spec.baumgarte);
    assert_eq!((spec.baumgarte_len(), spec.contact_ref_len()), (1, 7));
}
