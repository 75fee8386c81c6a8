//! The Rust emitter's contract: a snapshot of the chunked output for a small robot (so an
//! emitter change shows up as a readable diff), names from the URDF that cannot inject
//! code or escape the output folder, `Builder` errors that name the URDF problem, and
//! `--check` exit codes.

use grid_gen::generate::{generate, Options};
use grid_gen::Builder;
use grid_gen_test_support::*;

/// The double pendulum with at most 40 statements per function, so that the multi-
/// function path (scratch slots, parts) is in the snapshot.
#[test]
fn chunked_snapshot_of_a_small_robot() {
    let model = load("double_pendulum_continuous");
    let mut options = Options::default();
    options.rust.chunk = 40;
    let got = generate(&model, &options).unwrap().remove(0).contents;
    let path = repo().join("tests/snapshots/double_pendulum_chunk40.rs");
    if std::env::var_os("GRID_GEN_BLESS").is_some() {
        std::fs::write(&path, &got).unwrap();
    }
    let want = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(got == want, "snapshot differs; GRID_GEN_BLESS=1 cargo test -p grid-gen --test emit, then review `git diff tests/snapshots`");
}

const HOSTILE: &str = r#"<robot name="../../evil&quot;); std::process::exit(1); (&quot;">
  <link name="base"/>
  <link name="a"><inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <joint name="j&quot;]; fn x() {} //&#10;*/ \" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 1 1"/></joint>
</robot>"#;

#[test]
fn urdf_names_cannot_inject_code_or_paths() {
    // The file name is written into the header too.
    let (model, _) =
        grid_gen::Model::from_urdf_str("x/h.urdf\n}\nfn y() {}\n//", HOSTILE, false).unwrap();
    let file = generate(&model, &Options::default()).unwrap().remove(0);
    assert_eq!(file.name, "______evil____std__process__exit_1_____.rs");
    // The code parses, and its only items are the ones grid-gen writes.
    let parsed = syn::parse_file(&file.contents).unwrap();
    let names: Vec<String> = parsed
        .items
        .iter()
        .filter_map(|i| match i {
            syn::Item::Const(c) => Some(c.ident.to_string()),
            syn::Item::Fn(f) => Some(f.sig.ident.to_string()),
            syn::Item::Trait(t) => Some(t.ident.to_string()),
            syn::Item::Struct(t) => Some(t.ident.to_string()),
            syn::Item::Impl(_) => None,
            syn::Item::Mod(m) => {
                // The two machine-code copies hold the kernels (their `_into` bodies and
                // parts) only.
                for item in &m.content.as_ref().expect("inline module").1 {
                    match item {
                        syn::Item::Use(_) => {}
                        syn::Item::Fn(f) => {
                            let name = f.sig.ident.to_string();
                            let kernel = name.split("_part").next().unwrap();
                            let kernel = kernel.strip_suffix("_into").unwrap_or(kernel);
                            assert!(
                                [
                                    "rnea",
                                    "rnea_grad",
                                    "mass_matrix",
                                    "minv",
                                    "fd",
                                    "fd_grad",
                                    "integrate",
                                    "dintegrate",
                                    "difference",
                                    "ddifference"
                                ]
                                .contains(&kernel),
                                "unexpected fn {name}"
                            );
                        }
                        _ => panic!("unexpected item in mod {}", m.ident),
                    }
                }
                Some(format!("mod {}", m.ident))
            }
            _ => Some("unexpected item".to_string()),
        })
        .collect();
    assert_eq!(
        names,
        [
            "ROBOT",
            "NV",
            "NQ",
            "JOINT_NAMES",
            "PARENTS",
            "GRAVITY",
            "Real",
            "lit",
            "Lanes",
            "has_fma",
            "F64x4",
            "F32x8",
            "rnea",
            "rnea_into",
            "rnea_grad",
            "rnea_grad_into",
            "mass_matrix",
            "mass_matrix_into",
            "minv",
            "minv_into",
            "fd",
            "fd_into",
            "fd_grad",
            "fd_grad_into",
            "integrate",
            "integrate_into",
            "dintegrate",
            "dintegrate_into",
            "difference",
            "difference_into",
            "ddifference",
            "ddifference_into",
            "mod portable",
            "mod fma"
        ]
    );
    // The names survive exactly as string values.
    let lit = |name: &str| -> Vec<String> {
        parsed
            .items
            .iter()
            .find_map(|i| match i {
                syn::Item::Const(c) if c.ident == name => Some(c.expr.clone()),
                _ => None,
            })
            .map(|e| match *e {
                syn::Expr::Lit(syn::ExprLit { lit: syn::Lit::Str(s), .. }) => vec![s.value()],
                syn::Expr::Array(a) => a
                    .elems
                    .iter()
                    .map(|e| {
                        if let syn::Expr::Lit(syn::ExprLit { lit: syn::Lit::Str(s), .. }) = e {
                            s.value()
                        } else {
                            panic!()
                        }
                    })
                    .collect(),
                _ => panic!("not a literal"),
            })
            .unwrap()
    };
    assert_eq!(lit("ROBOT"), std::slice::from_ref(&model.name));
    assert_eq!(lit("JOINT_NAMES"), [model.joints[0].name.clone()]);
    // Comments only carry escaped names: no raw newline from the URDF or its file name.
    assert!(file.contents.lines().filter(|l| l.starts_with("//")).all(|l| !l.contains("fn x()")));
    // The file name (the last path component: `h.urdf`, a newline, `}`, ...) is escaped
    // onto one comment line.
    assert_eq!(
        grid_gen::back::source_of(&file.contents),
        Some("h.urdf\\u{a}}\\u{a}fn y() {}\\u{a}")
    );
}

/// The C target's files for the hostile robot: the Rust file's only module holds what
/// grid-gen writes, and a C program that includes the header compiles without a warning
/// and reads the names back unchanged.
#[test]
fn urdf_names_cannot_inject_code_into_the_c_abi() {
    use grid_gen::generate::Target;
    let (model, _) =
        grid_gen::Model::from_urdf_str("x/h.urdf\n*/ int evil;", HOSTILE, false).unwrap();
    let files =
        generate(&model, &Options { targets: vec![Target::C], ..Options::default() }).unwrap();
    let stem = "______evil____std__process__exit_1_____";
    assert_eq!(
        files.iter().map(|f| f.name.as_str()).collect::<Vec<_>>(),
        [format!("{stem}_c.rs"), format!("{stem}.h")]
    );
    let parsed = syn::parse_file(&files[0].contents).unwrap();
    assert_eq!(parsed.items.len(), 1);
    let syn::Item::Mod(m) = &parsed.items[0] else { panic!("one module") };
    assert_eq!(m.ident, format!("{stem}_batch"));
    for item in &m.content.as_ref().unwrap().1 {
        match item {
            syn::Item::Use(_) => {}
            syn::Item::Const(c) => {
                assert!([
                    "GRID_GEN_OK",
                    "GRID_GEN_NULL_POINTER",
                    "GRID_GEN_BAD_LENGTH",
                    "GRID_GEN_BAD_VALUE",
                    "MANIFEST",
                    "QUATERNIONS"
                ]
                .contains(&c.ident.to_string().as_str()))
            }
            // The thread's last bad state (`thread_local!`).
            syn::Item::Macro(m) => {
                assert!(m.mac.path.is_ident("thread_local"), "unexpected macro")
            }
            syn::Item::Fn(f) => {
                let name = f.sig.ident.to_string();
                let kernel = name
                    .strip_prefix(&format!("robot{stem}_"))
                    .unwrap_or(&name)
                    .trim_end_matches("_f64")
                    .trim_end_matches("_f32")
                    .trim_end_matches("_batch");
                assert!(
                    [
                        "rnea",
                        "rnea_grad",
                        "mass_matrix",
                        "minv",
                        "fd",
                        "fd_grad",
                        "integrate",
                        "dintegrate",
                        "difference",
                        "ddifference",
                        "set_threads",
                        "threads",
                        "manifest",
                        "bad_state",
                        "first_bad",
                        "gather",
                        "lane"
                    ]
                    .contains(&kernel),
                    "unexpected fn {name}"
                );
            }
            _ => panic!("unexpected item"),
        }
    }
    let dir = std::env::temp_dir().join(format!("grid-gen-hostile-c-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(&files[1].name), &files[1].contents).unwrap();
    // C reserves names that start with `_`: the C names start with `robot`.
    let upper = format!("ROBOT{}", stem.to_uppercase());
    std::fs::write(
        dir.join("main.c"),
        format!("#include <stdio.h>\n#include \"{stem}.h\"\nint main(void) {{ fputs({upper}_JOINT_NAMES[0], stdout); return {upper}_NV == 1 ? 0 : 1; }}\n"),
    )
    .unwrap();
    let cc = std::process::Command::new("cc")
        .current_dir(&dir)
        .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-o", "names", "main.c"])
        .output()
        .unwrap();
    assert!(cc.status.success(), "{}", String::from_utf8_lossy(&cc.stderr));
    let run = std::process::Command::new(dir.join("names")).output().unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(run.status.success());
    assert_eq!(String::from_utf8(run.stdout).unwrap(), model.joints[0].name);
}

/// A robot whose joints are all fixed still gets every kernel (of size zero), and the
/// module compiles without a single rustc warning.
#[test]
fn a_robot_without_movable_joints_compiles_without_warnings() {
    let urdf = r#"<robot name="statue">
  <link name="base"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <link name="head"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
  <joint name="neck" type="fixed"><parent link="base"/><child link="head"/></joint>
</robot>"#;
    let (model, _) = grid_gen::Model::from_urdf_str("statue.urdf", urdf, false).unwrap();
    let file = generate(&model, &Options::default()).unwrap().remove(0);
    let dir = std::env::temp_dir().join(format!("grid-gen-statue-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("statue.rs"), &file.contents).unwrap();
    std::fs::write(
        dir.join("lib.rs"),
        "mod statue { include!(\"statue.rs\"); }\n\
         pub fn all() -> usize { let z: [f64; 0] = []; statue::rnea(&z, &z, &z); statue::rnea_grad(&z, &z, &z); statue::mass_matrix(&z); \
         statue::minv(&z); statue::fd(&z, &z, &z); statue::fd_grad(&z, &z, &z); statue::NV }\n",
    )
    .unwrap();
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let out = std::process::Command::new(rustc)
        .args([
            "--edition",
            "2021",
            "--crate-type",
            "lib",
            "--emit",
            "metadata",
            "-D",
            "warnings",
            "--out-dir",
        ])
        .arg(&dir)
        .arg(dir.join("lib.rs"))
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

#[test]
fn builder_writes_once_and_names_urdf_problems() {
    let dir = std::env::temp_dir().join(format!("grid-gen-builder-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let urdf = repo().join("robots/grid_iiwa.urdf");
    let paths = Builder::new().urdf(&urdf).out_dir(&dir).quiet(true).compile().unwrap();
    assert_eq!(paths, vec![dir.join("iiwa14.rs")]);
    let path = &paths[0];
    let first = std::fs::metadata(path).unwrap().modified().unwrap();
    std::thread::sleep(std::time::Duration::from_millis(20));
    Builder::new().urdf(&urdf).out_dir(&dir).quiet(true).compile().unwrap();
    assert_eq!(
        std::fs::metadata(path).unwrap().modified().unwrap(),
        first,
        "unchanged contents are not rewritten"
    );

    let bad = repo().join("tests/diagnostics/unknown_parent.urdf");
    let err =
        Builder::new().urdf(&bad).out_dir(&dir).quiet(true).compile().unwrap_err().to_string();
    assert!(
        err.contains(
            "unknown_parent.urdf:4:36: error: joint `j1` names unknown parent link `bsae`"
        ),
        "{err}"
    );
    assert!(err.contains("help: correct the name or add the missing <link>"), "{err}");
    let err = Builder::new()
        .urdf(&urdf)
        .out_dir(&dir)
        .file_name("../x.rs")
        .quiet(true)
        .compile()
        .unwrap_err()
        .to_string();
    assert!(err.contains("must be a plain `*.rs` name"), "{err}");
    let err = Builder::new().out_dir(&dir).compile().unwrap_err().to_string();
    assert!(err.contains("no URDF given"), "{err}");
    let err = Builder::new()
        .urdf(&urdf)
        .out_dir(&dir)
        .emit(&[])
        .quiet(true)
        .compile()
        .unwrap_err()
        .to_string();
    assert!(err.contains("no targets selected"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The opt-in `avx512` copy (`--avx512`, `RustOptions::avx512`) runs the `fma` copy's
/// operations, so on a CPU with AVX-512 its outputs must equal the `fma` copy's bit for bit,
/// in f64, f32 and the 512-bit `F64x8`/`F32x16` (each of whose lanes must also equal one
/// scalar call: what `Lanes<8>` and `Lanes<16, f32>` compute by construction, without their
/// minutes of rustc), and the dispatcher must return the same. UR5's
/// gradients, so that the chunked path (scratch slots, parts) is compiled too. Without
/// AVX-512 here the module is still compiled (and its dispatcher run), and the test says
/// the copy did not run: a CPU feature cannot be installed.
#[test]
fn the_avx512_copy_matches_the_fma_copy_bit_for_bit() {
    let model = load("ur5");
    let options = Options {
        targets: vec![grid_gen::generate::Target::Rust],
        lower: grid_gen::ir::LowerOptions {
            kernels: vec![grid_gen::ir::KernelKind::RneaGrad, grid_gen::ir::KernelKind::FdGrad],
            ..Default::default()
        },
        rust: grid_gen::back::rust::RustOptions { avx512: true, ..Default::default() },
        ..Options::default()
    };
    let file = generate(&model, &options).unwrap().remove(0);
    assert!(
        file.contents.contains("pub mod avx512") && file.contents.contains("pub fn has_avx512()")
    );
    let default = generate(&model, &Options { rust: Default::default(), ..options.clone() })
        .unwrap()
        .remove(0);
    assert!(!default.contents.contains("avx512"), "the avx512 copy is opt-in");
    let said = compile_and_run(
        "avx512",
        &file.contents,
        r#"mod robot { include!("robot.rs"); }
use robot::*;
fn state(k: usize, i: usize, salt: usize) -> f64 { (((k * 7919 + i * 104_729 + salt * 15_485_863) % 2001) as f64 / 1000.0) * 3.0 - 1.5 }
fn bits<T: core::fmt::Debug>(x: T) -> String { format!("{x:?}") }
fn m<V: Copy, S>(x: &[[V; NV]; NV], f: impl Fn(V) -> S) -> [[S; NV]; NV] { x.map(|r| r.map(&f)) }
macro_rules! same {
    ($t:ty, $lift:expr) => {{
        for k in 0..8 {
            let x: [[$t; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| $lift(k, i, s)));
            let a = unsafe { (bits(fma::rnea_grad(&x[0], &x[1], &x[2])), bits(fma::fd_grad(&x[0], &x[1], &x[2]))) };
            let b = unsafe { (bits(avx512::rnea_grad(&x[0], &x[1], &x[2])), bits(avx512::fd_grad(&x[0], &x[1], &x[2]))) };
            let c = (bits(rnea_grad(&x[0], &x[1], &x[2])), bits(fd_grad(&x[0], &x[1], &x[2])));
            assert!(a == b && b == c, "{} state {k}: the avx512 copy differs from the fma copy", stringify!($t));
        }
    }};
}
fn main() {
    if !has_avx512() {
        let _ = fd_grad(&[0.1f64; NV], &[0.2; NV], &[0.3; NV]);
        println!("no AVX-512");
        return;
    }
    same!(f64, |k: usize, i: usize, s: usize| state(k, i, s));
    same!(f32, |k: usize, i: usize, s: usize| state(k, i, s) as f32);
    same!(F64x8, |k: usize, i: usize, s: usize| F64x8::new(std::array::from_fn(|l| state(k * 8 + l, i, s))).unwrap());
    same!(F32x16, |k: usize, i: usize, s: usize| F32x16::new(std::array::from_fn(|l| state(k * 16 + l, i, s) as f32)).unwrap());
    // Each lane of the explicit SIMD types is one scalar call of the same copy, bit for bit
    // (what the batch functions rely on); no `Lanes` here, whose arrays take rustc minutes.
    for k in 0..8 {
        for l in 0..8 {
            let x: [[f64; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| state(k * 8 + l, i, s)));
            let v: [[F64x8; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| F64x8::new(std::array::from_fn(|m| state(k * 8 + m, i, s))).unwrap()));
            let (a, b) = rnea_grad(&v[0], &v[1], &v[2]);
            let (c, d, e) = fd_grad(&v[0], &v[1], &v[2]);
            let got = (bits((m(&a, |y| y.to_array()[l]), m(&b, |y| y.to_array()[l]))), bits((c.map(|y| y.to_array()[l]), m(&d, |y| y.to_array()[l]), m(&e, |y| y.to_array()[l]))));
            let want = unsafe { (bits(avx512::rnea_grad(&x[0], &x[1], &x[2])), bits(avx512::fd_grad(&x[0], &x[1], &x[2]))) };
            assert!(got == want, "state {k}, lane {l}: F64x8 differs from one f64 call");
        }
        for l in 0..16 {
            let x: [[f32; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| state(k * 16 + l, i, s) as f32));
            let v: [[F32x16; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| F32x16::new(std::array::from_fn(|m| state(k * 16 + m, i, s) as f32)).unwrap()));
            let (a, b) = rnea_grad(&v[0], &v[1], &v[2]);
            let (c, d, e) = fd_grad(&v[0], &v[1], &v[2]);
            let got = (bits((m(&a, |y| y.to_array()[l]), m(&b, |y| y.to_array()[l]))), bits((c.map(|y| y.to_array()[l]), m(&d, |y| y.to_array()[l]), m(&e, |y| y.to_array()[l]))));
            let want = unsafe { (bits(avx512::rnea_grad(&x[0], &x[1], &x[2])), bits(avx512::fd_grad(&x[0], &x[1], &x[2]))) };
            assert!(got == want, "state {k}, lane {l}: F32x16 differs from one f32 call");
        }
    }
    println!("same");
}
"#,
    );
    let said = said.trim().to_string();
    match said.as_str() {
        "same" => println!(
            "ur5: the avx512 copy equals the fma copy bit for bit (f64, f32, F64x8, F32x16), and each lane of F64x8 and F32x16 one f64 or f32 call"
        ),
        "no AVX-512" => eprintln!(
            "note: this CPU has no AVX-512 F and VL; the avx512 copy was compiled but not run"
        ),
        other => panic!("unexpected output `{other}`"),
    }
}

/// `fd_grad` by the direct M⁻¹ (`Solve::Minv`, what `auto` picks on chains deeper than
/// `LTDL_MAX_DEPTH`, and by option): the `fma` copy runs its dense `−M⁻¹ ∂c/∂u` as a loop
/// instead of the graph's dot products, so it is compared with the portable copy (the
/// graph's order): within 1e-13 of each output's largest entry, FMA contraction and the
/// loop's summation order being the only differences (measured 2.3e-15 on iiwa).
#[test]
fn the_looped_product_matches_the_portable_copy() {
    let model = load("grid_iiwa");
    let lower = grid_gen::ir::LowerOptions {
        kernels: vec![grid_gen::ir::KernelKind::FdGrad],
        solve: grid_gen::ir::Solve::Minv,
        ..Default::default()
    };
    let options =
        Options { targets: vec![grid_gen::generate::Target::Rust], lower, ..Options::default() };
    let file = generate(&model, &options).unwrap().remove(0);
    assert!(
        file.contents.contains("r0[c] = T::mul_add(m, pd0[j][c], r0[c]);"),
        "the fma copy loops over the product"
    );
    let auto = generate(&model, &Options { lower: Default::default(), ..options.clone() })
        .unwrap()
        .remove(0);
    assert!(!auto.contents.contains("pd0[j][c]"), "auto factorises M on iiwa (no dense product)");
    let said = compile_and_run(
        "looped",
        &file.contents,
        r#"mod robot { include!("robot.rs"); }
use robot::*;
fn state(k: usize, i: usize, salt: usize) -> f64 { (((k * 7919 + i * 104_729 + salt * 15_485_863) % 2001) as f64 / 1000.0) * 3.0 - 1.5 }
fn main() {
    if !has_fma() {
        println!("no FMA");
        return;
    }
    let mut worst = 0.0f64;
    for k in 0..16 {
        let x: [[f64; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| state(k, i, s)));
        let a = unsafe { fma::fd_grad(&x[0], &x[1], &x[2]) };
        let b = portable::fd_grad(&x[0], &x[1], &x[2]);
        for (m, n) in [(a.1, b.1), (a.2, b.2)] {
            let scale = n.iter().flatten().fold(0.0f64, |s, v| s.max(v.abs()));
            let err = m.iter().flatten().zip(n.iter().flatten()).fold(0.0f64, |s, (u, v)| s.max((u - v).abs()));
            worst = worst.max(err / scale);
        }
    }
    println!("{worst:e}");
}
"#,
    );
    let said = said.trim().to_string();
    if said == "no FMA" {
        eprintln!("note: this CPU has no AVX2/FMA; the fma copy was compiled but not run");
        return;
    }
    let worst: f64 = said.parse().unwrap_or_else(|_| panic!("unexpected output `{said}`"));
    println!("iiwa fd_grad, direct M⁻¹: the fma copy's looped product is {worst:.1e} from the portable copy");
    assert!(worst <= 1e-13, "{worst:e}");
}

/// Which kernels' batches run in SIMD lanes: under `auto`, iiwa's dynamics kernels (lanes
/// measured 1.3x to 2.4x faster per state on them) and not its Lie-group kernels (one
/// operation or none per output entry: 0.8x for `integrate` and `difference`); `all` and
/// `none` as named. A kernel without lanes is never instantiated for `F64x4` or `F32x8`.
#[test]
fn batch_lanes_go_where_they_pay() {
    use grid_gen::back::c::{BatchLanes, COptions};
    use grid_gen::generate::Target;
    let model = load("grid_iiwa");
    let with_lanes = |lanes: BatchLanes| -> Vec<String> {
        let options = Options {
            targets: vec![Target::C],
            c: COptions { lanes, ..COptions::default() },
            ..Options::default()
        };
        let files = generate(&model, &options).unwrap();
        // Each safe batch function, up to the next item.
        let text = &files[0].contents;
        let mut out = Vec::new();
        for (at, _) in text.match_indices("<T: Real + Send + Sync + 'static>(") {
            let name = text[..at].rsplit("pub fn ").next().unwrap().to_string();
            let body = &text[at..];
            let body = &body[..body.find("\n    pub ").unwrap_or(body.len())];
            if body.contains("F64x4") {
                assert!(body.contains("F32x8"), "{name}: f64 lanes without f32 lanes");
                out.push(name);
            } else {
                assert!(!body.contains("F32x8"), "{name}: f32 lanes without f64 lanes");
            }
        }
        out
    };
    let dynamics = ["rnea", "rnea_grad", "mass_matrix", "minv", "fd", "fd_grad"];
    assert_eq!(with_lanes(BatchLanes::Auto), dynamics);
    let lie = ["integrate", "dintegrate", "difference", "ddifference"];
    assert_eq!(with_lanes(BatchLanes::All), [&dynamics[..], &lie[..]].concat());
    assert!(with_lanes(BatchLanes::None).is_empty());
}

/// With `kernel_features`, each kernel's items in the module and its C ABI sit behind a
/// Cargo feature of the kernel's name and the shared entry points behind `common`, and
/// `<robot>_features.json` names each kernel's callees, so that a crate compiles only the
/// kernels it turns on (`grid_gen.load` builds the others in other crates and links them:
/// `python/tests`, `test_a_large_robots_kernels_compile_as_crates_at_once`). Without it,
/// nothing is gated and there is no features file.
#[test]
fn kernel_features_gate_every_kernels_items() {
    use grid_gen::generate::Target;
    let model = load("grid_hyq");
    let emit = |on: bool| {
        let mut options = Options { targets: vec![Target::Rust, Target::C], ..Options::default() };
        options.rust.kernel_features = on;
        options.c.kernel_features = on;
        options.lower.kernels = vec![
            grid_gen::ir::KernelKind::Rnea,
            grid_gen::ir::KernelKind::RneaGrad,
            grid_gen::ir::KernelKind::Fd,
            grid_gen::ir::KernelKind::FdGrad,
        ];
        generate(&model, &options).unwrap()
    };
    let plain = emit(false);
    assert_eq!(plain.len(), 3, "the module, its C ABI and the header");
    assert!(plain.iter().all(|f| !f.contents.contains("cfg(feature")));
    let files = emit(true);
    let features: serde_json::Value = serde_json::from_str(
        &files.iter().find(|f| f.name.ends_with("_features.json")).unwrap().contents,
    )
    .unwrap();
    let kernels: Vec<String> = features["kernels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k["name"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(kernels, ["rnea", "rnea_grad", "fd", "fd_grad"]);
    assert!(features["kernels"]
        .as_array()
        .unwrap()
        .iter()
        .all(|k| k["weight"].as_u64().unwrap() > 0));
    let feature = |attrs: &[syn::Attribute]| -> Option<String> {
        attrs.iter().find(|a| a.path().is_ident("cfg")).and_then(|a| {
            let text = a.meta.require_list().ok()?.tokens.to_string();
            let name = text.strip_prefix("feature = \"")?.strip_suffix('"')?;
            Some(name.to_string())
        })
    };
    // The kernel an item belongs to: the longest kernel name its own name starts with.
    let owner = |name: &str| -> Option<String> {
        kernels
            .iter()
            .filter(|k| name == k.as_str() || name.starts_with(&format!("{k}_")))
            .max_by_key(|k| k.len())
            .cloned()
    };
    let module = syn::parse_file(&files[0].contents).unwrap();
    let mut gated = 0;
    for item in &module.items {
        match item {
            syn::Item::Fn(f) if kernels.contains(&f.sig.ident.to_string()) => {
                assert_eq!(feature(&f.attrs), Some(f.sig.ident.to_string()));
                gated += 1;
            }
            syn::Item::Mod(m) if m.ident == "portable" || m.ident == "fma" => {
                for inner in &m.content.as_ref().unwrap().1[1..] {
                    let (name, attrs) = match inner {
                        syn::Item::Fn(f) => (f.sig.ident.to_string(), &f.attrs),
                        syn::Item::Struct(s) => (s.ident.to_string(), &s.attrs),
                        syn::Item::Mod(m) => (m.ident.to_string(), &m.attrs),
                        syn::Item::Use(u) => match &u.tree {
                            syn::UseTree::Path(p) => (p.ident.to_string(), &u.attrs),
                            _ => panic!("an unexpected `use` in {}", m.ident),
                        },
                        _ => panic!("an unexpected kind of item in {}", m.ident),
                    };
                    let Some(kernel) = owner(&name) else {
                        // The column runner, which every kernel's program shares.
                        assert_eq!(feature(attrs), None, "{name}");
                        continue;
                    };
                    assert_eq!(feature(attrs), Some(kernel), "{}::{name}", m.ident);
                    gated += 1;
                }
            }
            _ => {}
        }
    }
    assert!(gated > 4 * 4, "every copy's items were seen ({gated})");
    let c = syn::parse_file(&files[1].contents).unwrap();
    let syn::Item::Mod(batch) = &c.items[0] else { panic!("the C ABI is one module") };
    let mut entry_points = 0;
    for item in &batch.content.as_ref().unwrap().1 {
        let syn::Item::Fn(f) = item else { continue };
        let name = f.sig.ident.to_string();
        let Some(rest) = name.strip_prefix("hyq_") else {
            if kernels.contains(&name) {
                assert_eq!(feature(&f.attrs), Some(name.clone()), "the batch function {name}");
            } else {
                assert!(feature(&f.attrs).is_none(), "{name}: a shared helper");
            }
            continue;
        };
        entry_points += 1;
        let kernel = rest.strip_suffix("_f64").or(rest.strip_suffix("_f32")).unwrap_or(rest);
        let kernel = kernel.strip_suffix("_batch").unwrap_or(kernel);
        let want = if kernels.iter().any(|k| k == kernel) { kernel } else { "common" };
        assert_eq!(feature(&f.attrs).as_deref(), Some(want), "{name}");
    }
    // Four kernels, two precisions, one state and a batch; four shared entry points: every
    // exported function.
    assert_eq!(entry_points, 4 * 2 * 2 + 4);
    assert_eq!(files[1].contents.matches("no_mangle").count(), entry_points);
}
