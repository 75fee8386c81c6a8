//! Contacts chosen at run time (`contact_mask = true`): one library whose contact kernels
//! and step take `active`, one 0 or 1 per candidate contact, serves every contact mode of a
//! gait. Each mode's values are those of the model holding just its active contacts (the
//! reference, itself checked against Pinocchio's `constraintDynamics` in `tests/forces.rs`,
//! and, for HyQ's sixteen modes, Pinocchio holding just those contacts), with λ's rows of
//! the inactive contacts 0.

use grid_gen::ir::{self, Input, KernelKind, LowerOptions};
use grid_gen::model::{ContactKind, Scheme};
use grid_gen::{reference, Model};
use grid_gen_test_support::*;
use nalgebra::DMatrix;

/// Floating HyQ with its four lower legs as candidate point contacts, a force on its base.
fn standing_hyq() -> Model {
    let legs = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
        .map(|l| (l, ContactKind::Point));
    let mut m = with_forces(&load_floating("grid_hyq"), &["root_joint"], &legs);
    m.specialisation.contact_mask = true;
    m
}

/// The mask `bits` (bit c: contact c holds) as the kernels take it and as the reference's.
fn mask(bits: usize, n: usize) -> (Vec<f64>, Vec<bool>) {
    let active: Vec<bool> = (0..n).map(|c| bits >> c & 1 == 1).collect();
    (active.iter().map(|&a| f64::from(u8::from(a))).collect(), active)
}

/// All sixteen modes of HyQ's four feet (none, one, two, three and four on the ground):
/// `contact_fd` and `contact_fd_grad` against the reference holding just those contacts,
/// on random states, with fext on the base.
#[test]
fn every_mode_of_four_feet_matches_the_reference_holding_those_contacts() {
    let m = standing_hyq();
    let g = reference::DEFAULT_GRAVITY;
    let options = LowerOptions {
        kernels: vec![KernelKind::ContactFd, KernelKind::ContactFdGrad],
        ..LowerOptions::default()
    };
    let module = ir::lower(&m, g, &options).unwrap();
    let mut rng = Rng(83);
    let nv = m.nv();
    let mut worst: f64 = 0.0;
    for f in &module.functions {
        assert_eq!(f.inputs().last(), Some(&Input::Active), "{}: takes the mask", f.kind);
    }
    for state in 0..2 {
        let q = m.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
        let (qd, u, fext) =
            (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -10.0, 10.0), rng.vec(6, -20.0, 20.0));
        let ext = reference::External { fext: &fext, lambda: &[] };
        for bits in 0..16 {
            let (values, active) = mask(bits, 4);
            for f in &module.functions {
                let got = f.eval(&kernel_args_masked(f.inputs(), &q, &qd, &u, ext, &[], &values));
                let want =
                    reference_masked_outputs(f.kind, &m, &q, &qd, &u, g, &fext, 0.0, &active);
                assert_eq!(got.len(), want.len(), "{}: outputs", f.kind);
                for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                    let got = DMatrix::from_row_slice(want.nrows(), want.ncols(), got);
                    let e = rel_err(&got, want);
                    worst = worst.max(e);
                    // The Schur complement against the reference's full KKT LU; HyQ's feet
                    // keep K well conditioned on these states (measured 2.3e-14), where
                    // tests/forces.rs allows 5e-11 for its worse-conditioned fixtures.
                    assert!(
                        e < 1e-12,
                        "state {state} mask {bits:04b} {} {}: {e:.2e}",
                        f.kind,
                        o.name
                    );
                    if o.name.starts_with("lambda") || o.name.starts_with("dlambda") {
                        // An inactive contact's rows are exactly 0, not small.
                        for (c, &a) in active.iter().enumerate() {
                            let rows = got.rows(3 * c, 3);
                            assert!(
                                a || rows.iter().all(|&x| x == 0.0),
                                "mask {bits:04b} {} contact {c}",
                                o.name
                            );
                        }
                    }
                }
            }
        }
    }
    println!("16 contact modes of floating HyQ: worst {worst:.2e} from the reference holding those contacts (bound 1e-12)");
}

/// The same sixteen modes against Pinocchio 4.1 directly: `constraintDynamics` and
/// `computeConstraintDynamicsDerivatives` holding just each mode's feet (none: plain
/// `aba`), one random state per mode (`tests/fixtures/grid_hyq.floating.contact_masks.
/// pinocchio.json`, rows of λ and its derivatives zero for the feet off the ground). 1e-10
/// relative, the project's bar against Pinocchio (tests/forces.rs).
#[test]
fn every_mode_of_four_feet_matches_pinocchio_holding_those_contacts() {
    let fx = fixture("grid_hyq.floating.contact_masks.pinocchio.json");
    let legs = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
        .map(|l| (l, ContactKind::Point));
    let mut m = with_forces(&load_floating("grid_hyq"), &[], &legs);
    m.specialisation.contact_mask = true;
    let fixture_feet: Vec<&str> =
        fx["contacts"].as_array().unwrap().iter().map(|c| c["frame"].as_str().unwrap()).collect();
    assert_eq!(fixture_feet, legs.map(|l| l.0), "the fixture's contacts, in order");
    let g: [f64; 3] = vec_of(&fx["gravity"]).try_into().unwrap();
    let options = LowerOptions {
        kernels: vec![KernelKind::ContactFd, KernelKind::ContactFdGrad],
        ..LowerOptions::default()
    };
    let module = ir::lower(&m, g, &options).unwrap();
    let perm = fixture_perm(&m, &fx, "contact masks");
    let nv = m.nv();
    let at = |i: usize| perm.iter().position(|&p| p == i).unwrap();
    let ours = |v: &[f64]| -> Vec<f64> { (0..nv).map(|i| v[at(i)]).collect() };
    let (mut worst, mut checked, mut modes): (f64, usize, Vec<usize>) = (0.0, 0, Vec::new());
    for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
        let active: Vec<f64> = vec_of(&st["active"]);
        modes.push(active.iter().enumerate().map(|(c, &a)| (a as usize) << c).sum());
        let fq = vec_of(&st["q"]);
        let angles = [vec![0.0; 6], fq[7..].to_vec()].concat();
        let q = m.q_from_joints(&ours(&angles), fq[..7].try_into().unwrap());
        let (qd, tau) = (ours(&vec_of(&st["qd"])), ours(&vec_of(&st["tau"])));
        let ext = reference::External { fext: &[], lambda: &[] };
        for f in &module.functions {
            let got = f.eval(&kernel_args_masked(f.inputs(), &q, &qd, &tau, ext, &[], &active));
            for (o, got) in f.outputs.iter().zip(&got) {
                let theirs = match o.name {
                    "qdd" => col(&ours(&vec_of(&st["qdd"]))),
                    "lambda" => col(&vec_of(&st["lambda"])),
                    name => {
                        let t = mat_of(&st[name]);
                        let square = name.starts_with("dqdd");
                        DMatrix::from_fn(t.nrows(), nv, |r, c| {
                            t[(if square { at(r) } else { r }, at(c))]
                        })
                    }
                };
                let got = DMatrix::from_row_slice(theirs.nrows(), theirs.ncols(), got);
                let e = rel_err(&got, &theirs);
                worst = worst.max(e);
                checked += 1;
                assert!(e < 1e-10, "mode {:?} (state {s}) {} {}: {e:.2e}", active, f.kind, o.name);
            }
        }
    }
    modes.sort_unstable();
    assert_eq!(modes, (0..16).collect::<Vec<_>>(), "every mode once");
    assert_eq!(checked, 16 * 10, "two outputs of contact_fd, eight of contact_fd_grad");
    println!("16 contact modes of floating HyQ against Pinocchio: worst {worst:.2e} (bound 1e-10)");
}

/// With every contact active, the masked kernels compute the unmasked kernels' values bit
/// for bit (the mask multiplies by 1 and adds 0), and cost a few operations more: two per
/// entry of K's lower triangle and one per row.
#[test]
fn all_active_is_the_unmasked_kernel() {
    let masked = standing_hyq();
    let mut plain = masked.clone();
    plain.specialisation.contact_mask = false;
    let g = reference::DEFAULT_GRAVITY;
    let options = LowerOptions {
        kernels: vec![KernelKind::ContactFd, KernelKind::ContactFdGrad],
        ..LowerOptions::default()
    };
    let (a, b) =
        (ir::lower(&masked, g, &options).unwrap(), ir::lower(&plain, g, &options).unwrap());
    let mut rng = Rng(89);
    let nv = plain.nv();
    let q = plain.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
    let (qd, u, fext) = (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -10.0, 10.0), rng.vec(6, -20.0, 20.0));
    let ext = reference::External { fext: &fext, lambda: &[] };
    for (f, fixed) in a.functions.iter().zip(&b.functions) {
        let got = f.eval(&kernel_args_masked(f.inputs(), &q, &qd, &u, ext, &[], &[1.0; 4]));
        let want = fixed.eval(&kernel_args_with(fixed.inputs(), &q, &qd, &u, ext));
        assert_eq!(got, want, "{}", f.kind);
        let ops = |f: &ir::Function| {
            (0..f.nodes.len()).filter(|&i| f.is_operation(ir::Id(i as u32))).count()
        };
        let nl = plain.nlambda();
        println!("floating HyQ {}: {} operations masked, {} not", f.kind, ops(f), ops(fixed));
        // m_r m_s once per pair of contacts, then a multiplication per entry of K's lower
        // triangle, 1 − m_r and an addition per diagonal entry, a multiplication per 1/D.
        assert!(ops(f) <= ops(fixed) + nl * (nl + 1) / 2 + 3 * nl + 10, "{}", f.kind);
    }
}

/// The step through a masked contact set: floating HyQ's semi-implicit `step` and
/// `step_grad` with a run-time dt, for a trot's two stances (diagonal pairs) and a flight
/// phase, against the reference step holding just those contacts.
#[test]
fn a_trot_steps_with_one_library() {
    let m = with_runtime_step(&standing_hyq(), Scheme::SemiImplicitEuler);
    let g = reference::DEFAULT_GRAVITY;
    let options = LowerOptions {
        kernels: vec![KernelKind::Step, KernelKind::StepGrad],
        ..LowerOptions::default()
    };
    let module = ir::lower(&m, g, &options).unwrap();
    let mut rng = Rng(97);
    let nv = m.nv();
    let mut worst: f64 = 0.0;
    for bits in [0b1001, 0b0110, 0b0000, 0b1111] {
        let (values, active) = mask(bits, 4);
        let q = m.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
        let (qd, u, fext) =
            (rng.vec(nv, -2.0, 2.0), rng.vec(m.nu(), -10.0, 10.0), rng.vec(6, -20.0, 20.0));
        let ext = reference::External { fext: &fext, lambda: &[] };
        let dt = [0.01];
        for f in &module.functions {
            let args = kernel_args_masked(f.inputs(), &q, &qd, &u, ext, &dt, &values);
            let got = f.eval(&args);
            let want = reference_masked_outputs(f.kind, &m, &q, &qd, &u, g, &fext, dt[0], &active);
            for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                let e = rel_err(&output_matrix(o.shape, nv, got), want);
                worst = worst.max(e);
                // As above, integrated over one step (measured 1.2e-14).
                assert!(e < 1e-12, "mask {bits:04b} {} {}: {e:.2e}", f.kind, o.name);
            }
        }
    }
    println!("floating HyQ's trot through one library: worst {worst:.2e} from the reference (bound 1e-12)");
}

/// A masked contact set through the generated Rust, compiled with rustc and run: iiwa with
/// points at its fifth and seventh links, `contact_fd_grad` in each of the four modes (one
/// state each, both copies), against the reference holding just the active contacts.
#[test]
fn masked_contacts_compile_and_match_the_reference() {
    use grid_gen::generate::{generate, Options, Target};
    let points = [("iiwa_link_5", ContactKind::Point), ("iiwa_link_7", ContactKind::Point)];
    let mut model = with_forces(&load("grid_iiwa"), &[], &points);
    model.specialisation.contact_mask = true;
    let lower =
        LowerOptions { kernels: vec![KernelKind::ContactFdGrad], ..LowerOptions::default() };
    let file =
        generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    assert!(file.contents.contains("pub const NCONTACTS: usize = 2;"));
    let said = compile_and_run(
        "contactmask",
        &file.contents,
        &[
            "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
            SEEDED_STATE_RS,
            r#"fn main() {
    for k in 0..4 {
        let x: [[f64; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| state(k, i, s)));
        let active = [(k & 1) as f64, (k >> 1 & 1) as f64];
        let one = contact_fd_grad(&x[0], &x[1], &x[2], &active);
        let two = portable::contact_fd_grad(&x[0], &x[1], &x[2], &active);
        let flat = |o: &(_, _, _, _, _, _, _, _)| -> Vec<f64> {
            let (a, l, b, c, d, e, f, g): &([f64; NV], [f64; NLAMBDA], [[f64; NV]; NV], [[f64; NV]; NV], [[f64; NV]; NV], [[f64; NV]; NLAMBDA], [[f64; NV]; NLAMBDA], [[f64; NV]; NLAMBDA]) = o;
            a.iter().chain(l).chain(b.as_flattened()).chain(c.as_flattened()).chain(d.as_flattened()).chain(e.as_flattened()).chain(f.as_flattened()).chain(g.as_flattened()).copied().collect()
        };
        let all: Vec<String> = flat(&one).iter().chain(&flat(&two)).map(|x| format!("{x:?}")).collect();
        println!("{}", all.join(" "));
    }
}
"#,
        ]
        .concat(),
    );
    let nv = model.nv();
    // f64 kernels are held to 1e-12 of the reference, as everywhere; the dispatched copy and
    // the portable one are printed one after the other and both checked.
    let worst = worst_line_error(&said, 4, 0, 1e-12, |k, _| {
        let x: Vec<Vec<f64>> =
            (0..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect();
        let active = [k & 1 == 1, k >> 1 & 1 == 1];
        let g = reference::DEFAULT_GRAVITY;
        let want = reference_masked_outputs(
            KernelKind::ContactFdGrad,
            &model,
            &x[0],
            &x[1],
            &x[2],
            g,
            &[],
            0.0,
            &active,
        );
        let one: Vec<f64> = want.iter().flat_map(|m| m.transpose().as_slice().to_vec()).collect();
        one.iter().chain(&one).copied().collect()
    });
    println!("iiwa contact_fd_grad in four modes, compiled: worst {worst:.2e} from the reference (bound 1e-12)");
}

/// A step kernel whose contact kernel is in the module shares it ([`ir::Call`]): the
/// callee's values, fed to the rest, give the whole graph's. Floating HyQ with four masked
/// feet and a force on its base, a run-time dt, three modes: both Euler schemes, and the
/// semi-implicit one with the feet stabilised (Baumgarte's gains and references, which the
/// callee takes too).
#[test]
fn the_step_kernels_rest_after_their_callee_is_the_whole_kernel() {
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(61);
    let mut worst: f64 = 0.0;
    for (scheme, baumgarte) in [
        (Scheme::SemiImplicitEuler, false),
        (Scheme::ExplicitEuler, false),
        (Scheme::SemiImplicitEuler, true),
    ] {
        let mut m = with_runtime_step(&standing_hyq(), scheme);
        m.specialisation.baumgarte = baumgarte;
        let module = ir::lower(&m, g, &LowerOptions::default()).unwrap();
        let nv = m.nv();
        for f in module.functions.iter().filter(|f| f.kind.is_step()) {
            let call = f.call.as_ref().unwrap_or_else(|| panic!("{} shares its callee", f.kind));
            let callee = module.function(call.callees[0]).unwrap();
            for bits in [0b1111, 0b0110, 0b0000] {
                let (active, _) = mask(bits, 4);
                let q = m.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
                let (qd, u, fext) =
                    (rng.vec(nv, -2.0, 2.0), rng.vec(m.nu(), -10.0, 10.0), rng.vec(6, -20.0, 20.0));
                let (gains, refs) = (rng.vec(8, 0.0, 30.0), rng.vec(12, -1.0, 1.0));
                let corr = reference::Baumgarte { gains: &gains, refs: &refs };
                let ext = reference::External { fext: &fext, lambda: &[] };
                let dt = [0.01];
                let args = kernel_args_corrected(f.inputs(), &q, &qd, &u, ext, &dt, &active, corr);
                let whole = f.eval(&args);
                let tau = actuated_tau(&m, &u);
                let called = callee.eval(&kernel_args_corrected(
                    callee.inputs(),
                    &q,
                    &qd,
                    &tau,
                    ext,
                    &dt,
                    &active,
                    corr,
                ));
                let mut rest_args: Vec<&[f64]> = args.clone();
                rest_args.extend(called.iter().map(Vec::as_slice));
                assert_eq!(rest_args.len(), call.rest.inputs().len());
                let parted = call.rest.eval(&rest_args);
                for ((o, a), b) in f.outputs.iter().zip(&whole).zip(&parted) {
                    let e = rel_err(&col(a), &col(b));
                    worst = worst.max(e);
                    // Two roundings of the same values: the callee forms all of ∂q̈/∂τ's
                    // symmetric half where the whole kernel forms the actuated columns, and
                    // mirrors the other entries (measured 7e-14); the f64 bound of every test.
                    assert!(
                        e < 1e-12,
                        "{scheme:?} baumgarte {baumgarte} {} {} mode {bits:04b}: {e:.2e}",
                        f.kind,
                        o.name
                    );
                }
            }
        }
    }
    println!(
        "step kernels as callee and rest: worst {worst:.2e} from the whole graph (bound 1e-12)"
    );
}

/// The shared step kernels through the generated Rust, compiled and run: iiwa with masked
/// points at its fifth and seventh links, joints 3 and 6 unactuated (so the callee's τ is
/// spread), a run-time dt and every contact and step kernel, so that `step` calls
/// `contact_fd` and `step_grad` calls `contact_fd_grad`. Four modes, both copies, against
/// the reference holding just the active contacts.
#[test]
fn shared_step_kernels_compile_and_match_the_reference() {
    let points = [("iiwa_link_5", ContactKind::Point), ("iiwa_link_7", ContactKind::Point)];
    let mut model = with_forces(&load("grid_iiwa"), &[], &points);
    model.specialisation.contact_mask = true;
    model.specialisation.actuated = Some(vec![0, 1, 3, 4, 6]);
    let model = with_runtime_step(&model, Scheme::SemiImplicitEuler);
    let kernels =
        [KernelKind::Step, KernelKind::StepGrad, KernelKind::ContactFd, KernelKind::ContactFdGrad];
    let worst = shared_steps_against_the_reference("sharedstep", &model, &kernels);
    println!("iiwa step and step_grad through their callees, compiled: worst {worst:.2e} from the reference (bound 1e-12)");
}

/// The same on a floating base, where the rest composes the free-flyer's block of `dt Jv`
/// and `Jq` with every column: floating iiwa, masked points at its fifth and seventh links,
/// the semi-implicit step with a run-time dt, four modes, both copies.
#[test]
fn shared_floating_step_grad_compiles_and_matches_the_reference() {
    let points = [("iiwa_link_5", ContactKind::Point), ("iiwa_link_7", ContactKind::Point)];
    let mut model = with_forces(&load_floating("grid_iiwa"), &[], &points);
    model.specialisation.contact_mask = true;
    let model = with_runtime_step(&model, Scheme::SemiImplicitEuler);
    let kernels = [KernelKind::StepGrad, KernelKind::ContactFdGrad];
    let worst = shared_steps_against_the_reference("sharedfloatingstep", &model, &kernels);
    println!("floating iiwa step_grad through contact_fd_grad, compiled: worst {worst:.2e} from the reference (bound 1e-12)");
}

/// A masked contact model's module with `kernels` (step kernels and their callees),
/// checked to share (each step kernel's rest; the spread τ where joints are unactuated),
/// compiled and run in four modes, both copies: its step kernels' outputs against the
/// reference holding just the active contacts, f64's 1e-12 as everywhere. The worst error.
fn shared_steps_against_the_reference(label: &str, model: &Model, kernels: &[KernelKind]) -> f64 {
    use grid_gen::generate::{generate, Options, Target};
    let steps: Vec<KernelKind> = kernels.iter().copied().filter(|k| k.is_step()).collect();
    let lower = LowerOptions { kernels: kernels.to_vec(), ..LowerOptions::default() };
    let lowered = ir::lower(model, reference::DEFAULT_GRAVITY, &lower).unwrap();
    for f in lowered.functions.iter().filter(|f| f.kind.is_step()) {
        assert!(f.call.is_some(), "{} calls its contact kernel", f.kind);
    }
    let file =
        generate(model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    for kind in &steps {
        let rest = format!("fn {kind}_rest<");
        assert!(file.contents.contains(&rest), "the module shares: {rest}");
    }
    if model.specialisation.actuated.is_some() {
        // iiwa's joints 3 and 6 unactuated: its τ's third entry is coordinate 3's.
        assert!(file.contents.contains("called_tau[3] = tau[2];"), "the callee's τ is spread");
    }
    let mut calls = String::new();
    if steps.contains(&KernelKind::Step) {
        calls.push_str(
            "for one in [step(&q, &qd, &u, &active, &dt), portable::step(&q, &qd, &u, &active, &dt)] {
            all.extend(one.0.iter().chain(&one.1).chain(&one.2));
        }\n",
        );
    }
    let main = r#"fn main() {
    for k in 0..4 {
        let mut q: [f64; NQ] = std::array::from_fn(|i| state(k, i, 0));
        if NQ > NV {
            let n = q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
            for x in &mut q[3..7] { *x /= n; }
        }
        let qd: [f64; NV] = std::array::from_fn(|i| state(k, i, 1));
        let u: [f64; NU] = std::array::from_fn(|i| state(k, i, 2));
        let active = [(k & 1) as f64, (k >> 1 & 1) as f64];
        let dt = [0.01];
        let mut all: Vec<f64> = q.to_vec();
        CALLS
        for g in [step_grad(&q, &qd, &u, &active, &dt), portable::step_grad(&q, &qd, &u, &active, &dt)] {
            all.extend(g.0.iter().chain(&g.1).chain(g.2.as_flattened()).chain(g.3.as_flattened()));
            all.extend(g.4.iter().chain(g.5.as_flattened()).chain(g.6.as_flattened()));
        }
        let all: Vec<String> = all.iter().map(|x| format!("{x:?}")).collect();
        println!("{}", all.join(" "));
    }
}
"#
    .replace("CALLS", &calls);
    let said = compile_and_run(
        label,
        &file.contents,
        &["mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n", SEEDED_STATE_RS, &main]
            .concat(),
    );
    let (nv, nu) = (model.nv(), model.nu());
    worst_line_error(&said, 4, model.nq(), 1e-12, |k, q| {
        let qd: Vec<f64> = (0..nv).map(|i| seeded_state(k, i, 1)).collect();
        let u: Vec<f64> = (0..nu).map(|i| seeded_state(k, i, 2)).collect();
        let active = [k & 1 == 1, k >> 1 & 1 == 1];
        let g = reference::DEFAULT_GRAVITY;
        let mut want = Vec::new();
        for &kind in &steps {
            let values = reference_masked_outputs(kind, model, q, &qd, &u, g, &[], 0.01, &active);
            let one: Vec<f64> =
                values.iter().flat_map(|m| m.transpose().as_slice().to_vec()).collect();
            want.extend(one.iter().chain(&one).copied());
        }
        want
    })
}
