//! Reads the `// nv:`, `// precision:` and `// entry:` lines that the WGSL backend writes
//! at the top of every shader (the contract between the generator and this runtime).

use grid_gen::back::wgsl::{EntryMeta, Precision};

#[derive(Clone, Debug, PartialEq)]
pub struct ShaderInfo {
    pub nv: usize,
    /// Entries of q per state: `// nq:` (a floating base), else nv.
    pub nq: usize,
    /// Entries of the step kernels' `u` (the actuated joints' τ): `// nu:`, else nv.
    pub nu: usize,
    /// Entries of the forces (`fext`, then λ) that rnea, rnea_grad, fd and fd_grad read
    /// after q̈ or τ in `u`: `// forces:`, else 0.
    pub forces: usize,
    /// Of those, the contact forces λ (`// lambda:`, else 0): the contact kernels solve
    /// for them, so their `u` holds τ and fext only.
    pub lambda: usize,
    /// Entries of the contact mask that the contact kernels and the step read in `u`
    /// (`// active:`, else 0).
    pub active: usize,
    /// Contacts with Baumgarte gains, each 2 gains in `u` after the mask (`// baumgarte:`,
    /// else 0).
    pub baumgarte: usize,
    /// Their references' entries after the gains: 3 per point contact, 7 per wrench contact
    /// (`// contact_ref:`, else 0).
    pub contact_ref: usize,
    /// Whether the step kernels read their time step as the last entry of each state's `u`
    /// (`// dt: input`).
    pub runtime_dt: bool,
    pub precision: Precision,
    pub entries: Vec<EntryMeta>,
    /// The cooperative entries' operation tables (binding 6) and constants (binding 7),
    /// from the `// prog:` and `// konst:` lines at the end of the file.
    pub prog: Vec<u32>,
    pub konst: Vec<f64>,
}

#[derive(Debug, thiserror::Error)]
pub enum HeaderError {
    #[error("the header has no `// {0}:` line (was it written by grid-gen's WGSL backend?)")]
    Missing(&'static str),
    #[error("header line `{line}`: {why}")]
    Bad { line: String, why: String },
}

impl ShaderInfo {
    pub fn parse(source: &str) -> Result<ShaderInfo, HeaderError> {
        let mut nv = None;
        let mut nq = None;
        let mut nu = None;
        let mut forces = 0;
        let mut lambda = 0;
        let mut runtime_dt = false;
        let mut active = 0;
        let mut baumgarte = 0;
        let mut contact_ref = 0;
        let mut precision = None;
        let mut entries = Vec::new();
        let mut tables = None;
        // The header ends at the first line that is not a comment.
        for line in source.lines().take_while(|l| l.starts_with("//")) {
            let bad = |why: &str| HeaderError::Bad { line: line.to_string(), why: why.to_string() };
            if let Some(v) = line.strip_prefix("// nv: ") {
                nv = Some(v.trim().parse::<usize>().map_err(|_| bad("not a count"))?);
            } else if let Some(v) = line.strip_prefix("// nq: ") {
                nq = Some(v.trim().parse::<usize>().map_err(|_| bad("not a count"))?);
            } else if let Some(v) = line.strip_prefix("// nu: ") {
                nu = Some(v.trim().parse::<usize>().map_err(|_| bad("not a count"))?);
            } else if let Some(v) = line.strip_prefix("// forces: ") {
                forces = v.trim().parse::<usize>().map_err(|_| bad("not a count"))?;
            } else if let Some(v) = line.strip_prefix("// lambda: ") {
                lambda = v.trim().parse::<usize>().map_err(|_| bad("not a count"))?;
            } else if let Some(v) = line.strip_prefix("// active: ") {
                active = v.trim().parse::<usize>().map_err(|_| bad("not a count"))?;
            } else if let Some(v) = line.strip_prefix("// baumgarte: ") {
                baumgarte = v.trim().parse::<usize>().map_err(|_| bad("not a count"))?;
            } else if let Some(v) = line.strip_prefix("// contact_ref: ") {
                contact_ref = v.trim().parse::<usize>().map_err(|_| bad("not a count"))?;
            } else if let Some(v) = line.strip_prefix("// dt: ") {
                if v.trim() != "input" {
                    return Err(bad("expected `input`"));
                }
                runtime_dt = true;
            } else if let Some(v) = line.strip_prefix("// tables: ") {
                let mut counts = [0usize; 2];
                for (k, key) in ["prog=", "konst="].iter().enumerate() {
                    let word = v
                        .split_whitespace()
                        .find_map(|w| w.strip_prefix(key))
                        .ok_or_else(|| bad(&format!("no `{key}`")))?;
                    counts[k] =
                        word.parse().map_err(|_| bad(&format!("`{key}` is not a count")))?;
                }
                tables = Some(counts);
            } else if let Some(v) = line.strip_prefix("// precision: ") {
                precision =
                    Some(Precision::parse(v.trim()).ok_or_else(|| bad("unknown precision"))?);
            } else if let Some(v) = line.strip_prefix("// entry: ") {
                entries.push(EntryMeta::parse(v).map_err(|why| bad(&why))?);
            }
        }
        let nv = nv.ok_or(HeaderError::Missing("nv"))?;
        let precision = precision.ok_or(HeaderError::Missing("precision"))?;
        // Shaders written before the tables existed have neither the line nor a
        // cooperative entry that needs them.
        let (prog, konst) = match tables {
            Some([words, values]) => read_tables(source, words, values, precision)?,
            None => (Vec::new(), Vec::new()),
        };
        Ok(ShaderInfo {
            nv,
            nq: nq.unwrap_or(nv),
            nu: nu.unwrap_or(nv),
            forces,
            lambda,
            active,
            baumgarte,
            contact_ref,
            runtime_dt,
            precision,
            entries,
            prog,
            konst,
        })
    }

    pub fn entry(&self, name: &str) -> Option<&EntryMeta> {
        self.entries.iter().find(|e| e.entry == name)
    }
}

/// The `// prog:` (hex words) and `// konst:` (decimal values, read in the shader's
/// precision so they round-trip exactly) lines, checked against the header's counts.
fn read_tables(
    source: &str,
    words: usize,
    values: usize,
    precision: Precision,
) -> Result<(Vec<u32>, Vec<f64>), HeaderError> {
    let mut prog = Vec::with_capacity(words);
    let mut konst = Vec::with_capacity(values);
    for line in source.lines() {
        let bad = |why: &str| HeaderError::Bad {
            line: line.chars().take(80).collect(),
            why: why.to_string(),
        };
        if let Some(v) = line.strip_prefix("// prog: ") {
            for w in v.split_whitespace() {
                prog.push(u32::from_str_radix(w, 16).map_err(|_| bad("not a hex word"))?);
            }
        } else if let Some(v) = line.strip_prefix("// konst: ") {
            for w in v.split_whitespace() {
                let x = match precision {
                    Precision::F32 => w.parse::<f32>().map(f64::from),
                    Precision::F64 => w.parse::<f64>(),
                };
                konst.push(x.map_err(|_| bad("not a number"))?);
            }
        }
    }
    if prog.len() != words || konst.len() != values {
        return Err(HeaderError::Bad {
            line: format!("// tables: prog={words} konst={values}"),
            why: format!(
                "the file's `// prog:` and `// konst:` lines hold {} words and {} values",
                prog.len(),
                konst.len()
            ),
        });
    }
    Ok((prog, konst))
}

#[cfg(test)]
mod tests {
    use super::*;
    use grid_gen::back::wgsl::{emit_with_stats, WgslOptions};

    fn shader(precision: Precision) -> String {
        let model = grid_gen_test_support::load("double_pendulum_continuous");
        let module =
            grid_gen::ir::lower(&model, grid_gen::reference::DEFAULT_GRAVITY, &Default::default())
                .unwrap();
        emit_with_stats(&module, &WgslOptions { precision, ..WgslOptions::default() })
            .unwrap()
            .0
            .contents
    }

    /// The emitter's metadata is what the runtime reads back, field for field.
    #[test]
    fn every_entry_reads_back_as_the_emitter_wrote_it() {
        let model = grid_gen_test_support::load("double_pendulum_continuous");
        let module =
            grid_gen::ir::lower(&model, grid_gen::reference::DEFAULT_GRAVITY, &Default::default())
                .unwrap();
        let (file, written) = emit_with_stats(&module, &WgslOptions::default()).unwrap();
        assert_eq!(ShaderInfo::parse(&file.contents).unwrap().entries, written);
        let line = written[0].header_line();
        let bad = line.replace("outputs=", "outputs=x");
        assert!(ShaderInfo::parse(&bad)
            .unwrap_err()
            .to_string()
            .contains("`outputs` is not a count"));
    }

    #[test]
    fn the_tables_round_trip_in_both_precisions() {
        for precision in [Precision::F32, Precision::F64] {
            let text = shader(precision);
            let info = ShaderInfo::parse(&text).unwrap();
            // Ten kernels (six dynamics, four Lie-group), two strategies.
            assert_eq!(info.entries.len(), 20);
            // The cooperative entries' tables tile prog in order, each a head of (offset,
            // steps) per phase, the first block just past it, each block `steps` rows of
            // one instruction (3 words) per invocation, the last ending the table (the
            // ranges the generated comments give).
            let ranges: Vec<(usize, usize)> = text
                .lines()
                .filter_map(|l| {
                    l.split_once("a table at prog[")?.1.split_once(']')?.0.split_once("..")
                })
                .map(|(a, b)| (a.parse().unwrap(), b.parse().unwrap()))
                .collect();
            let coop: Vec<&EntryMeta> = info
                .entries
                .iter()
                .filter(|e| e.strategy == grid_gen::back::wgsl::Strategy::Cooperative)
                .collect();
            assert_eq!(ranges.len(), coop.len());
            let mut at = 0;
            for ((a, b), e) in ranges.into_iter().zip(coop) {
                assert_eq!(a, at, "{}", e.entry);
                let mut block = a + 2 * e.phases;
                for p in 0..e.phases {
                    assert_eq!(info.prog[a + 2 * p] as usize, block, "{} phase {p}", e.entry);
                    block += info.prog[a + 2 * p + 1] as usize * e.workgroup_size as usize * 3;
                }
                assert_eq!(block, b, "{}", e.entry);
                at = b;
            }
            assert_eq!(at, info.prog.len());
            if precision == Precision::F32 {
                assert!(info.konst.iter().all(|&c| c as f32 as f64 == c));
            }
        }
    }

    #[test]
    fn a_damaged_table_is_a_clear_error() {
        let text = shader(Precision::F32);
        let cut: String = text
            .lines()
            .filter(|l| !l.starts_with("// konst: "))
            .map(|l| format!("{l}\n"))
            .collect();
        let e = ShaderInfo::parse(&cut).unwrap_err().to_string();
        assert!(e.contains("prog=") && e.contains("values"), "{e}");
        let bad = text.replacen("// prog: ", "// prog: zz ", 1);
        let e = ShaderInfo::parse(&bad).unwrap_err().to_string();
        assert!(e.contains("not a hex word"), "{e}");
        let e = ShaderInfo::parse("// precision: f32\nfn main() {}").unwrap_err().to_string();
        assert!(e.contains("`// nv:`"), "{e}");
    }
}
