//! Criterion benchmarks of every generated f64 kernel against the reference dynamics, for
//! iiwa, HyQ and Atlas. `scripts/bench.sh` runs these beside Pinocchio and prints the
//! book's table; run alone with `cargo bench -p grid-gen-kernels --bench kernels`.
//!
//! Each iteration cycles through 64 fixed pseudo-random states so that branch predictors
//! and caches see what an optimiser's sweep over knot points shows them.

use std::hint::black_box;

/// Keeps a kernel's result alive through a reference. Returned from `iter`'s closure (or
/// passed by value to `black_box`), the result was moved by value once or twice more per
/// call: up to 14 KB of outputs copied (floating HyQ's `step_grad`), a cost a caller that
/// receives the result in place never pays and Pinocchio's benchmark, which writes into its
/// `Data`, does not include; its speed also moved with the stack's layout.
#[inline(always)]
fn keep<O>(o: O) {
    black_box(&o);
}

use criterion::{criterion_group, criterion_main, Criterion};
use grid_gen::{reference, Model};

const STATES: usize = 64;

fn load(stem: &str) -> Model {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../robots")
        .join(format!("{stem}.urdf"));
    Model::from_urdf_str(stem, &std::fs::read_to_string(path).unwrap(), false).unwrap().0
}

fn state(k: usize, i: usize, salt: usize) -> f64 {
    (((k * 7919 + i * 104_729 + salt * 15_485_863) % 2001) as f64 / 1000.0) - 1.0
}

macro_rules! bench_robot {
    ($c:expr, $m:ident, $stem:literal) => {{
        use grid_gen_kernels::$m as k;
        const N: usize = k::NV;
        let model = load($stem);
        let s: Vec<[[f64; N]; 3]> = (0..STATES)
            .map(|j| std::array::from_fn(|salt| std::array::from_fn(|i| state(j, i, salt))))
            .collect();
        let v: Vec<[Vec<f64>; 3]> = s.iter().map(|x| x.map(|a| a.to_vec())).collect();
        let g = reference::DEFAULT_GRAVITY;
        let mut group = $c.benchmark_group($stem);
        let mut j = 0usize;
        let mut next = || {
            j = (j + 1) % STATES;
            j
        };
        group.bench_function("generated/rnea", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::rnea(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("generated/rnea_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::rnea_grad(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("generated/portable/rnea_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::portable::rnea_grad(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("generated/portable/fd_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::portable::fd_grad(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("generated/mass_matrix", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::mass_matrix(&x[0]))
            })
        });
        group.bench_function("generated/minv", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::minv(&x[0]))
            })
        });
        group.bench_function("generated/fd", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::fd(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("generated/fd_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::fd_grad(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("reference/rnea", |b| {
            b.iter(|| {
                let x = &v[next()];
                keep(reference::rnea(&model, &x[0], &x[1], &x[2], g))
            })
        });
        group.bench_function("reference/rnea_grad", |b| {
            b.iter(|| {
                let x = &v[next()];
                keep(reference::rnea_derivatives(&model, &x[0], &x[1], &x[2], g))
            })
        });
        group.bench_function("reference/mass_matrix", |b| {
            b.iter(|| {
                let x = &v[next()];
                keep(reference::crba(&model, &x[0]))
            })
        });
        group.bench_function("reference/minv", |b| {
            b.iter(|| {
                let x = &v[next()];
                keep(reference::minv(&model, &x[0]))
            })
        });
        group.bench_function("reference/fd", |b| {
            b.iter(|| {
                let x = &v[next()];
                keep(reference::forward_dynamics(&model, &x[0], &x[1], &x[2], g))
            })
        });
        group.bench_function("reference/fd_grad", |b| {
            b.iter(|| {
                let x = &v[next()];
                keep(reference::forward_dynamics_derivatives(&model, &x[0], &x[1], &x[2], g))
            })
        });
        group.finish();
    }};
}

/// The gradients with N states per call in `Lanes<N>` (time per call; the report divides
/// by N). Not for Atlas: LLVM takes over ten minutes to optimise its 94k-statement
/// `fd_grad` four lanes wide.
macro_rules! bench_lanes {
    ($c:expr, $m:ident, $stem:literal) => {{
        use grid_gen_kernels::$m as k;
        const N: usize = k::NV;
        let l2: Vec<[[k::Lanes<2>; N]; 3]> = (0..STATES)
            .map(|j| {
                std::array::from_fn(|salt| {
                    std::array::from_fn(|i| {
                        k::Lanes(std::array::from_fn(|l| state(j + l * STATES, i, salt)))
                    })
                })
            })
            .collect();
        let l4: Vec<[[k::Lanes<4>; N]; 3]> = (0..STATES)
            .map(|j| {
                std::array::from_fn(|salt| {
                    std::array::from_fn(|i| {
                        k::Lanes(std::array::from_fn(|l| state(j + l * STATES, i, salt)))
                    })
                })
            })
            .collect();
        let mut group = $c.benchmark_group($stem);
        let mut j = 0usize;
        let mut next = || {
            j = (j + 1) % STATES;
            j
        };
        group.bench_function("generated/rnea_grad_lanes2", |b| {
            b.iter(|| {
                let x = &l2[next()];
                keep(k::rnea_grad(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("generated/fd_grad_lanes2", |b| {
            b.iter(|| {
                let x = &l2[next()];
                keep(k::fd_grad(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("generated/rnea_grad_lanes4", |b| {
            b.iter(|| {
                let x = &l4[next()];
                keep(k::rnea_grad(&x[0], &x[1], &x[2]))
            })
        });
        group.bench_function("generated/fd_grad_lanes4", |b| {
            b.iter(|| {
                let x = &l4[next()];
                keep(k::fd_grad(&x[0], &x[1], &x[2]))
            })
        });
        group.finish();
    }};
}

/// The gradients with four states per call in `F64x4` (one AVX register; time per call,
/// the report divides by 4), where the CPU has AVX2 and FMA. Unlike `Lanes<4>` it is for
/// Atlas too: with one vector instruction per operation LLVM optimises Atlas's `fd_grad`
/// in about a minute.
macro_rules! bench_f64x4 {
    ($c:expr, $m:ident, $stem:literal) => {{
        use grid_gen_kernels::$m as k;
        const N: usize = k::NV;
        if !k::F64x4::supported() {
            eprintln!("note: this CPU has no AVX2 and FMA: no F64x4 rows for {}", $stem);
        } else {
            let x4: Vec<[[k::F64x4; N]; 3]> = (0..STATES)
                .map(|j| {
                    std::array::from_fn(|salt| {
                        std::array::from_fn(|i| {
                            k::F64x4::new(std::array::from_fn(|l| state(j + l * STATES, i, salt)))
                                .expect("supported: checked above")
                        })
                    })
                })
                .collect();
            let mut group = $c.benchmark_group($stem);
            let mut j = 0usize;
            let mut next = || {
                j = (j + 1) % STATES;
                j
            };
            group.bench_function("generated/rnea_grad_f64x4", |b| {
                b.iter(|| {
                    let x = &x4[next()];
                    keep(k::rnea_grad(&x[0], &x[1], &x[2]))
                })
            });
            group.bench_function("generated/fd_grad_f64x4", |b| {
                b.iter(|| {
                    let x = &x4[next()];
                    keep(k::fd_grad(&x[0], &x[1], &x[2]))
                })
            });
            group.finish();
        }
    }};
}

/// The gradients of a robot in a scene (`examples/scenes/`), under the same state protocol:
/// `grid_iiwa.iiwa_wrist_locked/generated/fd_grad` against `grid_iiwa/generated/fd_grad`.
macro_rules! bench_scene {
    ($c:expr, $m:ident, $name:literal) => {{
        use grid_gen_kernels::scenes::$m as k;
        const N: usize = k::NV;
        // q has NQ entries (a floating base's quaternion: the kernels normalise it).
        let s: Vec<([f64; k::NQ], [[f64; N]; 2])> = (0..STATES)
            .map(|j| {
                (
                    std::array::from_fn(|i| state(j, i, 0)),
                    std::array::from_fn(|salt| std::array::from_fn(|i| state(j, i, salt + 1))),
                )
            })
            .collect();
        let mut group = $c.benchmark_group($name);
        let mut j = 0usize;
        let mut next = || {
            j = (j + 1) % STATES;
            j
        };
        group.bench_function("generated/rnea_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::rnea_grad(&x.0, &x.1[0], &x.1[1]))
            })
        });
        group.bench_function("generated/fd_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::fd_grad(&x.0, &x.1[0], &x.1[1]))
            })
        });
        group.finish();
    }};
}

/// The frame kernels of a frame scene (`examples/scenes/iiwa_tool_frame.toml`,
/// `hyq_feet_floating.toml`): `frame_jacobian` and `frame_acceleration`, every frame of the
/// scene per call, under the same state protocol.
macro_rules! bench_frames {
    ($c:expr, $m:ident, $name:literal) => {{
        use grid_gen_kernels::scenes::$m as k;
        const N: usize = k::NV;
        let s: Vec<([f64; k::NQ], [[f64; N]; 2])> = (0..STATES)
            .map(|j| {
                (
                    std::array::from_fn(|i| state(j, i, 0)),
                    std::array::from_fn(|salt| std::array::from_fn(|i| state(j, i, salt + 1))),
                )
            })
            .collect();
        let mut group = $c.benchmark_group($name);
        let mut j = 0usize;
        let mut next = || {
            j = (j + 1) % STATES;
            j
        };
        group.bench_function("generated/frame_jacobian", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::frame_jacobian(&x.0))
            })
        });
        group.bench_function("generated/frame_acceleration", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::frame_acceleration(&x.0, &x.1[0], &x.1[1]))
            })
        });
        group.finish();
    }};
}

/// The step scene (`examples/scenes/hyq_step_floating.toml`): `step_grad` beside
/// `fd_grad` of the same module (the step's target: within 1.2x), and `step`, under the
/// same state protocol; each q's quaternion normalised.
macro_rules! bench_step {
    ($c:expr, $m:ident, $name:literal) => {{
        use grid_gen_kernels::scenes::$m as k;
        let s: Vec<([f64; k::NQ], [f64; k::NV], [f64; k::NV], [f64; k::NU])> = (0..STATES)
            .map(|j| {
                let mut q: [f64; k::NQ] = std::array::from_fn(|i| state(j, i, 0));
                let n = q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
                q[3..7].iter_mut().for_each(|x| *x /= n);
                (
                    q,
                    std::array::from_fn(|i| state(j, i, 1)),
                    std::array::from_fn(|i| state(j, i, 2)),
                    std::array::from_fn(|i| state(j, i, 3)),
                )
            })
            .collect();
        let mut group = $c.benchmark_group($name);
        let mut j = 0usize;
        let mut next = || {
            j = (j + 1) % STATES;
            j
        };
        group.bench_function("generated/fd_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::fd_grad(&x.0, &x.1, &x.2))
            })
        });
        group.bench_function("generated/step_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::step_grad(&x.0, &x.1, &x.3))
            })
        });
        group.bench_function("generated/step", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::step(&x.0, &x.1, &x.3))
            })
        });
        group.finish();
    }};
}

/// The forces scene (`examples/scenes/hyq_contacts_floating.toml`: fext on all thirteen
/// bodies, four point contacts, with their derivative outputs) beside the same robot
/// without forces (`hyq_floating.toml`), `rnea_grad` and `fd_grad`, in one group so the
/// ratios come from one run (the target: within 1.3x of the kernels without forces).
macro_rules! bench_forces {
    ($c:expr) => {{
        use grid_gen_kernels::scenes::grid_hyq_contacts_floating as k;
        use grid_gen_kernels::scenes::grid_hyq_floating as plain;
        let s: Vec<([f64; k::NQ], [[f64; k::NV]; 2], [f64; 6 * k::NFEXT], [f64; k::NLAMBDA])> = (0
            ..STATES)
            .map(|j| {
                (
                    std::array::from_fn(|i| state(j, i, 0)),
                    std::array::from_fn(|salt| std::array::from_fn(|i| state(j, i, salt + 1))),
                    std::array::from_fn(|i| 10.0 * state(j, i, 3)),
                    std::array::from_fn(|i| 50.0 * state(j, i, 4)),
                )
            })
            .collect();
        let mut group = $c.benchmark_group("grid_hyq.hyq_contacts_floating");
        let mut j = 0usize;
        let mut next = || {
            j = (j + 1) % STATES;
            j
        };
        group.bench_function("generated/rnea_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::rnea_grad(&x.0, &x.1[0], &x.1[1], &x.2, &x.3))
            })
        });
        group.bench_function("without forces/rnea_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(plain::rnea_grad(&x.0, &x.1[0], &x.1[1]))
            })
        });
        group.bench_function("generated/fd_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::fd_grad(&x.0, &x.1[0], &x.1[1], &x.2, &x.3))
            })
        });
        group.bench_function("without forces/fd_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(plain::fd_grad(&x.0, &x.1[0], &x.1[1]))
            })
        });
        group.finish();
    }};
}

/// Rigid-contact dynamics (`examples/scenes/hyq_standing_floating.toml`: floating HyQ on
/// four point contacts): `contact_fd` and `contact_fd_grad`, beside `fd_grad` without
/// contacts (`hyq_floating.toml`) for scale; Pinocchio's `constraintDynamics` and its
/// derivatives are timed by bench/pinocchio_bench.cpp in the same run of scripts/bench.sh.
macro_rules! bench_contact {
    ($c:expr) => {{
        use grid_gen_kernels::scenes::grid_hyq_floating as plain;
        use grid_gen_kernels::scenes::grid_hyq_standing_floating as k;
        let s: Vec<([f64; k::NQ], [[f64; k::NV]; 2])> = (0..STATES)
            .map(|j| {
                let mut q: [f64; k::NQ] = std::array::from_fn(|i| state(j, i, 0));
                let n = q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
                q[3..7].iter_mut().for_each(|x| *x /= n);
                (q, std::array::from_fn(|salt| std::array::from_fn(|i| state(j, i, salt + 1))))
            })
            .collect();
        let mut group = $c.benchmark_group("grid_hyq.hyq_standing_floating");
        let mut j = 0usize;
        let mut next = || {
            j = (j + 1) % STATES;
            j
        };
        group.bench_function("generated/contact_fd", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::contact_fd(&x.0, &x.1[0], &x.1[1]))
            })
        });
        group.bench_function("generated/contact_fd_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(k::contact_fd_grad(&x.0, &x.1[0], &x.1[1]))
            })
        });
        group.bench_function("without contacts/fd_grad", |b| {
            b.iter(|| {
                let x = &s[next()];
                keep(plain::fd_grad(&x.0, &x.1[0], &x.1[1]))
            })
        });
        group.finish();
    }};
}

fn kernels(c: &mut Criterion) {
    if std::env::var_os("GRID_GEN_BENCH_FORCES_ONLY").is_some() {
        bench_forces!(c);
        return;
    }
    if std::env::var_os("GRID_GEN_BENCH_CONTACT_ONLY").is_some() {
        bench_contact!(c);
        return;
    }
    if std::env::var_os("GRID_GEN_BENCH_STEP_ONLY").is_some() {
        bench_step!(c, grid_hyq_step_floating, "grid_hyq.hyq_step_floating");
        return;
    }
    if std::env::var_os("GRID_GEN_BENCH_FRAMES_ONLY").is_some() {
        bench_frames!(c, grid_iiwa_tool_frame, "grid_iiwa.iiwa_tool_frame");
        bench_frames!(c, grid_hyq_feet_floating, "grid_hyq.hyq_feet_floating");
        return;
    }
    bench_robot!(c, grid_iiwa, "grid_iiwa");
    bench_robot!(c, grid_hyq, "grid_hyq");
    bench_robot!(c, grid_atlas, "grid_atlas");
    bench_lanes!(c, grid_iiwa, "grid_iiwa");
    bench_lanes!(c, grid_hyq, "grid_hyq");
    bench_f64x4!(c, grid_iiwa, "grid_iiwa");
    bench_f64x4!(c, grid_hyq, "grid_hyq");
    bench_f64x4!(c, grid_atlas, "grid_atlas");
    bench_scene!(c, grid_iiwa_wrist_locked, "grid_iiwa.iiwa_wrist_locked");
    bench_scene!(c, grid_hyq_front_legs, "grid_hyq.hyq_front_legs");
    bench_scene!(c, grid_iiwa_static, "grid_iiwa.iiwa_static");
    bench_scene!(c, grid_hyq_lf_columns, "grid_hyq.hyq_lf_columns");
    bench_scene!(c, grid_hyq_floating, "grid_hyq.hyq_floating");
    bench_scene!(c, grid_hyq_round_angles, "grid_hyq.hyq_round_angles");
    bench_scene!(c, grid_hyq_floating_round_angles, "grid_hyq.hyq_floating_round_angles");
    bench_frames!(c, grid_iiwa_tool_frame, "grid_iiwa.iiwa_tool_frame");
    bench_frames!(c, grid_hyq_feet_floating, "grid_hyq.hyq_feet_floating");
    bench_step!(c, grid_hyq_step_floating, "grid_hyq.hyq_step_floating");
    bench_forces!(c);
    bench_contact!(c);
}

criterion_group! {
    name = benches;
    config = Criterion::default().warm_up_time(std::time::Duration::from_millis(500)).measurement_time(std::time::Duration::from_secs(2)).sample_size(30);
    targets = kernels
}
criterion_main!(benches);
