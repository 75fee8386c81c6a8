//! iiwa's C ABI, called as a C program would (raw pointers, statuses), against the
//! reference dynamics: every kernel in f64 and f32, one state and a batch, on one thread
//! and on all of them.

use grid_gen::reference;
use grid_gen_test_support::*;
use grid_iiwa::iiwa14::{NQ, NV};
use grid_iiwa::iiwa14_batch::*;

/// States of iiwa drawn from the library's seeded generator.
fn states(n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut rng = Rng(7);
    let mut draw =
        |len: usize, scale: f64| (0..len).map(|_| rng.uniform(-scale, scale)).collect::<Vec<f64>>();
    (draw(n * NQ, 2.0), draw(n * NV, 1.5), draw(n * NV, 20.0))
}

fn max_rel(got: &[f64], want: &[f64]) -> f64 {
    let scale = want.iter().fold(0.0f64, |m, x| m.max(x.abs())).max(1e-300);
    got.iter().zip(want).fold(0.0f64, |m, (a, b)| m.max((a - b).abs())) / scale
}

#[test]
fn batches_match_the_reference_in_f64_and_f32() {
    let model = load("grid_iiwa");
    let g = reference::DEFAULT_GRAVITY;
    let n = 37;
    let (q, qd, tau) = states(n);
    let mut qdd = vec![0.0; n * NV];
    let mut dq = vec![0.0; n * NV * NV];
    let mut dqd = vec![0.0; n * NV * NV];
    let mut c = vec![0.0; n * NV];
    let mut m = vec![0.0; n * NV * NV];
    // SAFETY: every array holds n states.
    unsafe {
        assert_eq!(
            iiwa14_fd_grad_batch_f64(
                n,
                q.as_ptr(),
                qd.as_ptr(),
                tau.as_ptr(),
                qdd.as_mut_ptr(),
                dq.as_mut_ptr(),
                dqd.as_mut_ptr()
            ),
            GRID_GEN_OK
        );
        assert_eq!(
            iiwa14_rnea_batch_f64(n, q.as_ptr(), qd.as_ptr(), qdd.as_ptr(), c.as_mut_ptr()),
            GRID_GEN_OK
        );
        assert_eq!(iiwa14_mass_matrix_batch_f64(n, q.as_ptr(), m.as_mut_ptr()), GRID_GEN_OK);
    }
    let (mut worst_fd, mut worst_rnea, mut worst_m) = (0.0f64, 0.0f64, 0.0f64);
    for i in 0..n {
        let s = |v: &[f64], len: usize| v[i * len..(i + 1) * len].to_vec();
        let (want_qdd, want_dq, want_dqd) = reference::forward_dynamics_derivatives(
            &model,
            &s(&q, NQ),
            &s(&qd, NV),
            &s(&tau, NV),
            g,
        );
        let row_major = |m: &nalgebra::DMatrix<f64>| m.transpose().as_slice().to_vec();
        worst_fd = worst_fd
            .max(max_rel(&s(&qdd, NV), &want_qdd))
            .max(max_rel(&s(&dq, NV * NV), &row_major(&want_dq)))
            .max(max_rel(&s(&dqd, NV * NV), &row_major(&want_dqd)));
        worst_rnea = worst_rnea.max(max_rel(&s(&c, NV), &s(&tau, NV)));
        worst_m =
            worst_m.max(max_rel(&s(&m, NV * NV), &row_major(&reference::crba(&model, &s(&q, NQ)))));
    }
    println!("C ABI f64, {n} states: fd_grad {worst_fd:.1e}, rnea(fd) - tau {worst_rnea:.1e}, mass_matrix {worst_m:.1e} (tolerance 1e-12)");
    // Measured ~1e-14: f64 round-off through M^-1 at random states (the kernels crate
    // allows 5e-12 on bigger robots); a wrong layout or state stride would be O(1).
    assert!(worst_fd < 1e-12 && worst_rnea < 1e-12 && worst_m < 1e-12);

    let (q32, qd32, tau32): (Vec<f32>, Vec<f32>, Vec<f32>) = (
        q.iter().map(|&x| x as f32).collect(),
        qd.iter().map(|&x| x as f32).collect(),
        tau.iter().map(|&x| x as f32).collect(),
    );
    let mut qdd32 = vec![0.0f32; n * NV];
    let mut dq32 = vec![0.0f32; n * NV * NV];
    let mut dqd32 = vec![0.0f32; n * NV * NV];
    // SAFETY: every array holds n states.
    let status = unsafe {
        iiwa14_fd_grad_batch_f32(
            n,
            q32.as_ptr(),
            qd32.as_ptr(),
            tau32.as_ptr(),
            qdd32.as_mut_ptr(),
            dq32.as_mut_ptr(),
            dqd32.as_mut_ptr(),
        )
    };
    assert_eq!(status, GRID_GEN_OK);
    let widen = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
    let err32 = max_rel(&widen(&qdd32), &qdd)
        .max(max_rel(&widen(&dq32), &dq))
        .max(max_rel(&widen(&dqd32), &dqd));
    println!("C ABI f32 fd_grad against f64: {err32:.1e} (tolerance 1e-4)");
    // Measured ~2e-6: f32 rounding (6e-8) amplified by iiwa's M^-1 at these states (its
    // condition number is in the hundreds at worst); a wrong layout would be O(1).
    assert!(err32 < 1e-4);
}

#[test]
fn one_thread_and_every_core_give_the_same_bits() {
    let n = 203;
    let (q, qd, tau) = states(n);
    let run = |threads: usize| {
        iiwa14_set_threads(threads);
        assert_eq!(iiwa14_threads(), if threads == 0 { iiwa14_threads() } else { threads });
        let mut qdd = vec![0.0; n * NV];
        let mut dq = vec![0.0; n * NV * NV];
        let mut dqd = vec![0.0; n * NV * NV];
        // SAFETY: every array holds n states.
        let status = unsafe {
            iiwa14_fd_grad_batch_f64(
                n,
                q.as_ptr(),
                qd.as_ptr(),
                tau.as_ptr(),
                qdd.as_mut_ptr(),
                dq.as_mut_ptr(),
                dqd.as_mut_ptr(),
            )
        };
        assert_eq!(status, GRID_GEN_OK);
        (qdd, dq, dqd)
    };
    let one = run(1);
    let all = run(0);
    let three = run(3);
    iiwa14_set_threads(0);
    assert!(
        one == all && one == three,
        "a state's result does not depend on the thread that ran it"
    );
    // Every state of the batch is the one-state entry point's result, bit for bit: the
    // batch runs groups of four states in one F64x4 call where the CPU has AVX2 and FMA
    // (n = 203 leaves a scalar tail), and a lane computes what a scalar call does.
    for i in 0..n {
        let mut qdd = [0.0; NV];
        let mut dq = [0.0; NV * NV];
        let mut dqd = [0.0; NV * NV];
        // SAFETY: one state each.
        let status = unsafe {
            iiwa14_fd_grad_f64(
                q[i * NQ..].as_ptr(),
                qd[i * NV..].as_ptr(),
                tau[i * NV..].as_ptr(),
                qdd.as_mut_ptr(),
                dq.as_mut_ptr(),
                dqd.as_mut_ptr(),
            )
        };
        assert_eq!(status, GRID_GEN_OK);
        let (v, m) = (i * NV..(i + 1) * NV, i * NV * NV..(i + 1) * NV * NV);
        assert!(
            qdd[..] == one.0[v] && dq[..] == one.1[m.clone()] && dqd[..] == one.2[m],
            "state {i}: the batch differs from a one-state call"
        );
    }
}

#[test]
fn null_pointers_and_impossible_lengths_are_statuses() {
    let (q, qd, tau) = states(1);
    let mut out = vec![0.0; NV * NV];
    let null = std::ptr::null_mut::<f64>();
    // SAFETY: the calls must refuse before touching memory.
    unsafe {
        assert_eq!(
            iiwa14_fd_f64(q.as_ptr(), std::ptr::null(), tau.as_ptr(), out.as_mut_ptr()),
            GRID_GEN_NULL_POINTER
        );
        assert_eq!(iiwa14_minv_batch_f64(3, q.as_ptr(), null), GRID_GEN_NULL_POINTER);
        assert_eq!(
            iiwa14_rnea_batch_f32(
                5,
                std::ptr::null(),
                std::ptr::null(),
                std::ptr::null(),
                std::ptr::null_mut()
            ),
            GRID_GEN_NULL_POINTER
        );
        assert_eq!(
            iiwa14_minv_batch_f64(usize::MAX / 8, q.as_ptr(), out.as_mut_ptr()),
            GRID_GEN_BAD_LENGTH
        );
        assert_eq!(
            iiwa14_minv_batch_f64(0, std::ptr::null(), null),
            GRID_GEN_OK,
            "n = 0 does nothing"
        );
        assert_eq!(
            iiwa14_fd_f64(q.as_ptr(), qd.as_ptr(), tau.as_ptr(), out.as_mut_ptr()),
            GRID_GEN_OK
        );
    }
    assert!(out.iter().all(|x| x.is_finite()) && out[..NV].iter().any(|&x| x != 0.0));
}

/// iiwa has no quaternion, so its entry points check nothing: a NaN in gives NaN out, for
/// that state alone, and no call sets `iiwa14_bad_state` (a floating base's quaternions are
/// checked: `python/tests`, through ctypes).
#[test]
fn without_quaternions_nothing_is_checked() {
    let (q, mut qd, tau) = states(4);
    qd[2 * NV + 3] = f64::NAN;
    let mut out = vec![7.0; 4 * NV];
    // SAFETY: each pointer holds four states' arrays.
    let status =
        unsafe { iiwa14_fd_batch_f64(4, q.as_ptr(), qd.as_ptr(), tau.as_ptr(), out.as_mut_ptr()) };
    assert_eq!((status, iiwa14_bad_state()), (GRID_GEN_OK, -1));
    assert!(out[2 * NV..3 * NV].iter().all(|x| x.is_nan()), "the NaN's state");
    assert!(out[..2 * NV].iter().chain(&out[3 * NV..]).all(|x| x.is_finite()), "the others");
}

#[test]
fn the_manifest_describes_the_library() {
    // SAFETY: a static NUL-terminated string.
    let text = unsafe { std::ffi::CStr::from_ptr(iiwa14_manifest()) }.to_str().unwrap();
    let m: serde_json::Value = serde_json::from_str(text).unwrap();
    assert_eq!(m["nq"], NQ);
    assert_eq!(m["nv"], NV);
    assert_eq!(m["joint_names"][6], "iiwa_joint_7");
    let fd_grad = m["kernels"].as_array().unwrap().iter().find(|k| k["name"] == "fd_grad").unwrap();
    assert_eq!(
        fd_grad["inputs"],
        serde_json::json!([{"name": "q", "len": 7}, {"name": "qd", "len": 7}, {"name": "tau", "len": 7}])
    );
    assert_eq!(fd_grad["outputs"][1], serde_json::json!({"name": "dqdd_dq", "dims": [7, 7]}));
}
