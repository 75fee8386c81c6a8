//! One step of what an MPC solver does at a knot point: forward dynamics and its
//! gradient, then an explicit-Euler linearisation `x⁺ ≈ A x + B u` of the iiwa.

mod iiwa {
    include!(concat!(env!("OUT_DIR"), "/iiwa.rs"));
}

use iiwa::NV;

fn main() {
    let dt = 0.01;
    let q: [f64; NV] = [0.1, -0.4, 0.3, 1.2, -0.5, 0.6, 0.2];
    let qd: [f64; NV] = [0.5, 0.1, -0.2, 0.3, 0.0, -0.1, 0.4];
    let tau: [f64; NV] = [1.0, 20.0, 0.5, -10.0, 0.2, 1.0, 0.1];
    let (qdd, dqdd_dq, dqdd_dqd) = iiwa::fd_grad(&q, &qd, &tau);
    let minv = iiwa::minv(&q);
    // A = [[I, dt I], [dt ∂q̈/∂q, I + dt ∂q̈/∂q̇]], B = [[0], [dt M⁻¹]].
    let a_qq = (0..NV).map(|i| dt * dqdd_dq[i][i]).sum::<f64>();
    let b_norm = (0..NV)
        .flat_map(|i| (0..NV).map(move |j| (i, j)))
        .map(|(i, j)| (dt * minv[i][j]).abs())
        .fold(0.0, f64::max);
    println!("joints: {}", iiwa::JOINT_NAMES.join(" "));
    println!("qdd: {}", qdd.map(|x| format!("{x:.17e}")).join(" "));
    println!("dqdd_dq[1]: {}", dqdd_dq[1].map(|x| format!("{x:.17e}")).join(" "));
    println!("dqdd_dqd[1]: {}", dqdd_dqd[1].map(|x| format!("{x:.17e}")).join(" "));
    println!("trace(dt dqdd/dq) = {a_qq:.6}, max |B| = {b_norm:.6}");
}
