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
    let (model, _) = grid_gen::Model::from_urdf_str("x/h.urdf\n}\nfn y() {}\n//", HOSTILE, false).unwrap();
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
                // The two machine-code copies hold the kernels (and their parts) only.
                for item in &m.content.as_ref().expect("inline module").1 {
                    match item {
                        syn::Item::Use(_) => {}
                        syn::Item::Fn(f) => {
                            let name = f.sig.ident.to_string();
                            let kernel = name.split("_part").next().unwrap();
                            assert!(["rnea", "rnea_grad", "mass_matrix", "minv", "fd", "fd_grad"].contains(&kernel), "unexpected fn {name}");
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
            "Lanes",
            "has_fma",
            "rnea",
            "rnea_grad",
            "mass_matrix",
            "minv",
            "fd",
            "fd_grad",
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
                syn::Expr::Array(a) => {
                    a.elems.iter().map(|e| if let syn::Expr::Lit(syn::ExprLit { lit: syn::Lit::Str(s), .. }) = e { s.value() } else { panic!() }).collect()
                }
                _ => panic!("not a literal"),
            })
            .unwrap()
    };
    assert_eq!(lit("ROBOT"), [model.name.clone()]);
    assert_eq!(lit("JOINT_NAMES"), [model.joints[0].name.clone()]);
    // Comments only carry escaped names: no raw newline from the URDF or its file name.
    assert!(file.contents.lines().filter(|l| l.starts_with("//")).all(|l| !l.contains("fn x()")));
    // The file name (the last path component: `h.urdf`, a newline, `}`, ...) is escaped
    // onto one comment line.
    assert_eq!(grid_gen::back::source_of(&file.contents), Some("h.urdf\\u{a}}\\u{a}fn y() {}\\u{a}"));
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
        .args(["--edition", "2021", "--crate-type", "lib", "--emit", "metadata", "-D", "warnings", "--out-dir"])
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
    assert_eq!(std::fs::metadata(path).unwrap().modified().unwrap(), first, "unchanged contents are not rewritten");

    let bad = repo().join("tests/diagnostics/unknown_parent.urdf");
    let err = Builder::new().urdf(&bad).out_dir(&dir).quiet(true).compile().unwrap_err().to_string();
    assert!(err.contains("unknown_parent.urdf:4:36: error: joint `j1` names unknown parent link `bsae`"), "{err}");
    assert!(err.contains("help: correct the name or add the missing <link>"), "{err}");
    let err = Builder::new().urdf(&urdf).out_dir(&dir).file_name("../x.rs").quiet(true).compile().unwrap_err().to_string();
    assert!(err.contains("must be a plain `*.rs` name"), "{err}");
    let err = Builder::new().out_dir(&dir).compile().unwrap_err().to_string();
    assert!(err.contains("no URDF given"), "{err}");
    let err = Builder::new().urdf(&urdf).out_dir(&dir).emit(&[]).quiet(true).compile().unwrap_err().to_string();
    assert!(err.contains("no targets selected"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
