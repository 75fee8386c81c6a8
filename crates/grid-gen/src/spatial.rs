//! Spatial (6D) algebra on nalgebra types, after Featherstone, *Rigid Body Dynamics
//! Algorithms* (2008), ch. 2. Vectors are ordered [angular; linear] everywhere in grid-gen.

use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};

pub type Vec6 = Vector6<f64>;
pub type Mat6 = Matrix6<f64>;

pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// URDF roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll), the child axes in parent coordinates.
pub fn rpy_matrix(rpy: [f64; 3]) -> Matrix3<f64> {
    let (sr, cr) = rpy[0].sin_cos();
    let (sp, cp) = rpy[1].sin_cos();
    let (sy, cy) = rpy[2].sin_cos();
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, cr, -sr, 0.0, sr, cr);
    let ry = Matrix3::new(cp, 0.0, sp, 0.0, 1.0, 0.0, -sp, 0.0, cp);
    let rz = Matrix3::new(cy, -sy, 0.0, sy, cy, 0.0, 0.0, 0.0, 1.0);
    rz * ry * rx
}

/// Rotation by `angle` about the unit `axis` (Rodrigues).
pub fn axis_angle(axis: &Vector3<f64>, angle: f64) -> Matrix3<f64> {
    let (s, c) = angle.sin_cos();
    let k = skew(axis);
    Matrix3::identity() + k * s + k * k * (1.0 - c)
}

/// Motion transform from frame A to frame B, where B's origin sits at `r` (in A
/// coordinates) and `e` maps A coordinates to B coordinates: Featherstone's
/// `plux(E, r)` = [E 0; -E r× E].
pub fn plux(e: &Matrix3<f64>, r: &Vector3<f64>) -> Mat6 {
    let mut x = Mat6::zeros();
    x.fixed_view_mut::<3, 3>(0, 0).copy_from(e);
    x.fixed_view_mut::<3, 3>(3, 3).copy_from(e);
    x.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-e * skew(r)));
    x
}

/// Motion cross product matrix: `crm(v) m = v × m`.
pub fn crm(v: &Vec6) -> Mat6 {
    let w = Vector3::new(v[0], v[1], v[2]);
    let l = Vector3::new(v[3], v[4], v[5]);
    let mut x = Mat6::zeros();
    x.fixed_view_mut::<3, 3>(0, 0).copy_from(&skew(&w));
    x.fixed_view_mut::<3, 3>(3, 3).copy_from(&skew(&w));
    x.fixed_view_mut::<3, 3>(3, 0).copy_from(&skew(&l));
    x
}

/// Force cross product matrix: `crf(v) f = v ×* f = -crm(v)ᵀ f`.
pub fn crf(v: &Vec6) -> Mat6 {
    -crm(v).transpose()
}

/// Spatial inertia from mass, first moment `h = m c` and the rotational inertia about the
/// frame origin: [I_o, h×; -h× (= h×ᵀ), m 1] (Featherstone eq. 2.63).
pub fn spatial_inertia(mass: f64, h: &Vector3<f64>, i_origin: &Matrix3<f64>) -> Mat6 {
    let mut x = Mat6::zeros();
    x.fixed_view_mut::<3, 3>(0, 0).copy_from(i_origin);
    x.fixed_view_mut::<3, 3>(0, 3).copy_from(&skew(h));
    x.fixed_view_mut::<3, 3>(3, 0).copy_from(&skew(h).transpose());
    x.fixed_view_mut::<3, 3>(3, 3).copy_from(&(Matrix3::identity() * mass));
    x
}

/// The rotation of quaternion `[x, y, z, w]` (Pinocchio's and Eigen's storage order),
/// scaled by 1/|q|² so that a slightly non-unit quaternion gives the rotation of its
/// normalised self (Eigen's `toRotationMatrix` formula with s = 2/|q|²).
pub fn quaternion_matrix(q: [f64; 4]) -> Matrix3<f64> {
    let [x, y, z, w] = q;
    let s = 2.0 / (x * x + y * y + z * z + w * w);
    Matrix3::new(
        1.0 - s * (y * y + z * z),
        s * (x * y - z * w),
        s * (x * z + y * w),
        s * (x * y + z * w),
        1.0 - s * (x * x + z * z),
        s * (y * z - x * w),
        s * (x * z - y * w),
        s * (y * z + x * w),
        1.0 - s * (x * x + y * y),
    )
}
