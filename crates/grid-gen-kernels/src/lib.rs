//! The generated Rust kernels for every robot in `robots/`, as checked in under
//! `generated/<robot>/`. One module per robot; see any module's `rnea`, `rnea_grad`,
//! `mass_matrix`, `minv`, `fd`, `fd_grad`.

/// Runs `$body` once per robot module, with `$m` bound to the module and `$stem` to the
/// robot's file stem in `robots/`.
#[macro_export]
macro_rules! for_each_robot {
    ($mac:ident) => {
        $mac!(double_pendulum_continuous, "double_pendulum_continuous");
        $mac!(grid_atlas, "grid_atlas");
        $mac!(grid_hyq, "grid_hyq");
        $mac!(grid_iiwa, "grid_iiwa");
        $mac!(panda, "panda");
        $mac!(rbd_benchmarks_iiwa, "rbd_benchmarks_iiwa");
        $mac!(ur5, "ur5");
    };
}

pub mod double_pendulum_continuous {
    include!("../../../generated/double_pendulum_continuous/robot_2dof_planar.rs");
}
pub mod grid_atlas {
    include!("../../../generated/grid_atlas/atlas.rs");
}
pub mod grid_hyq {
    include!("../../../generated/grid_hyq/hyq.rs");
}
pub mod grid_iiwa {
    include!("../../../generated/grid_iiwa/iiwa14.rs");
}
pub mod panda {
    include!("../../../generated/panda/panda.rs");
}
pub mod rbd_benchmarks_iiwa {
    include!("../../../generated/rbd_benchmarks_iiwa/lbr_iiwa.rs");
}
pub mod ur5 {
    include!("../../../generated/ur5/ur5.rs");
}

/// Test robots that use grid-gen's extensions of URDF, as checked in under
/// `generated/fixtures/`: compiled here so that their kernels are run in the tests.
pub mod fixtures {
    /// `tests/fixtures/ball_arm.urdf`: three spherical joints.
    pub mod ball_arm {
        include!("../../../generated/fixtures/ball_arm/ball_arm.rs");
    }
}

/// Robots in the scenes of `examples/scenes/` (scene specialisation), as
/// checked in under `generated/scenes/`: benchmarked beside the full robots.
pub mod scenes {
    /// iiwa with joints 5 to 7 locked and a 2 kg tool: `rnea_grad` and `fd_grad` only.
    pub mod grid_iiwa_wrist_locked {
        include!("../../../generated/scenes/grid_iiwa.iiwa_wrist_locked/iiwa14.rs");
    }
    /// HyQ without its hind legs.
    pub mod grid_hyq_front_legs {
        include!("../../../generated/scenes/grid_hyq.hyq_front_legs/hyq.rs");
    }
    /// iiwa held still (`static = true`): no velocity terms, `qd` ignored.
    pub mod grid_iiwa_static {
        include!("../../../generated/scenes/grid_iiwa.iiwa_static/iiwa14.rs");
    }
    /// HyQ, gradient columns of the front-left leg only.
    pub mod grid_hyq_lf_columns {
        include!("../../../generated/scenes/grid_hyq.hyq_lf_columns/hyq.rs");
    }
    /// HyQ on a floating base (`floating_base = true`, as `--floating-base`): q has
    /// `NQ` = 19 entries, the rest `NV` = 18.
    pub mod grid_hyq_floating {
        include!("../../../generated/scenes/grid_hyq.hyq_floating/hyq.rs");
    }
    /// The Panda with its fingers coupled (`mimic = "coupled"`, as `--mimic coupled`):
    /// `NV` = 8, the second finger follows the first.
    pub mod panda_mimic {
        include!("../../../generated/scenes/panda.panda_mimic/panda.rs");
    }
    /// iiwa's flange as a frame: the four frame kernels, LOCAL_WORLD_ALIGNED.
    pub mod grid_iiwa_tool_frame {
        include!("../../../generated/scenes/grid_iiwa.iiwa_tool_frame/iiwa14.rs");
    }
    /// Floating HyQ's four lower legs as frames: the four frame kernels.
    pub mod grid_hyq_feet_floating {
        include!("../../../generated/scenes/grid_hyq.hyq_feet_floating/hyq.rs");
    }
    /// Floating HyQ's semi-implicit Euler step of 10 ms and its `[A | B]`, with `fd_grad`.
    pub mod grid_hyq_step_floating {
        include!("../../../generated/scenes/grid_hyq.hyq_step_floating/hyq.rs");
    }
    /// Floating HyQ with fext on every body and its four lower legs as point contacts:
    /// rnea, rnea_grad, fd and fd_grad with the forces as inputs.
    pub mod grid_hyq_contacts_floating {
        include!("../../../generated/scenes/grid_hyq.hyq_contacts_floating/hyq.rs");
    }
    /// Floating HyQ standing on its four lower legs as rigid point contacts: contact_fd
    /// and contact_fd_grad (q̈ and the contact forces λ, and their derivatives).
    pub mod grid_hyq_standing_floating {
        include!("../../../generated/scenes/grid_hyq.hyq_standing_floating/hyq.rs");
    }
    /// HyQ with its URDF's right angles read as right angles (`round_angles = 1e-11`):
    /// rnea_grad and fd_grad.
    pub mod grid_hyq_round_angles {
        include!("../../../generated/scenes/grid_hyq.hyq_round_angles/hyq.rs");
    }
    /// Floating HyQ with `round_angles = 1e-11`: rnea_grad and fd_grad.
    pub mod grid_hyq_floating_round_angles {
        include!("../../../generated/scenes/grid_hyq.hyq_floating_round_angles/hyq.rs");
    }
}
