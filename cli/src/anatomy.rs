//! `hydrometra anatomy`: generate a parametric uterus mesh (VTU for ParaView, JSON summary, and the
//! mesh itself as JSON for the FEM).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use hydrometra_sim::anatomy::{generate, write_vtu, AnatomyParams, Parity};

/// Parity preset for `--print-defaults`.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum PresetArg {
    /// Never given birth.
    Nulliparous,
    /// Given birth (the default).
    Parous,
}

/// Arguments of `hydrometra anatomy`.
#[derive(Args, Debug)]
pub struct AnatomyArgs {
    /// Parameter file (TOML). Keys not given come from its `parity` preset; without a file the
    /// parous defaults are used.
    #[arg(long, value_name = "FILE")]
    pub params: Option<PathBuf>,
    /// Output directory (created if missing): uterus.vtu, summary.json, mesh.json.
    #[arg(long, value_name = "DIR", required_unless_present = "print_defaults")]
    pub out: Option<PathBuf>,
    /// Print the default parameters as TOML (a starting point for a parameter file) and exit.
    #[arg(long, conflicts_with_all = ["params", "out"])]
    pub print_defaults: bool,
    /// Preset printed by --print-defaults.
    #[arg(
        long,
        value_enum,
        default_value = "parous",
        requires = "print_defaults"
    )]
    pub preset: PresetArg,
}

/// Runs `hydrometra anatomy`.
pub fn run(args: &AnatomyArgs) -> Result<()> {
    if args.print_defaults {
        let parity = match args.preset {
            PresetArg::Nulliparous => Parity::Nulliparous,
            PresetArg::Parous => Parity::Parous,
        };
        print!("{}", AnatomyParams::preset(parity).to_toml_string()?);
        return Ok(());
    }
    let params = match &args.params {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("reading parameter file {}", path.display()))?;
            AnatomyParams::from_toml_str(&text)
                .with_context(|| format!("in parameter file {}", path.display()))?
        }
        None => AnatomyParams::default(),
    };
    let out = args
        .out
        .as_ref()
        .context("--out DIR is required (or use --print-defaults)")?;
    let start = std::time::Instant::now();
    let source = args
        .params
        .as_ref()
        .map_or("the parous defaults".to_string(), |p| {
            p.display().to_string()
        });
    let anatomy =
        generate(&params).with_context(|| format!("generating the anatomy from {source}"))?;
    let elapsed = start.elapsed();
    std::fs::create_dir_all(out)
        .with_context(|| format!("creating output directory {}", out.display()))?;
    write_vtu(&anatomy.mesh, &out.join("uterus.vtu"))?;
    let summary_path = out.join("summary.json");
    std::fs::write(&summary_path, anatomy.summary_json()?)
        .with_context(|| format!("writing {}", summary_path.display()))?;
    let mesh_path = out.join("mesh.json");
    std::fs::write(&mesh_path, serde_json::to_string(&anatomy.mesh)?)
        .with_context(|| format!("writing {}", mesh_path.display()))?;
    let s = &anatomy.summary;
    println!(
        "anatomy: {} tets, {} vertices, {} cavity triangles in {:.2} s",
        s.tets,
        s.vertices,
        s.cavity_triangles,
        elapsed.as_secs_f64()
    );
    println!(
        "volumes: uterus {:.1} ml, tissue {:.1} ml, cavity at rest {:.2} ml",
        s.uterine_volume_ml, s.tissue_volume_ml, s.cavity_volume_ml
    );
    println!(
        "quality: dihedral min {:.1} / mean {:.1} / max {:.1} deg, aspect max {:.2} / mean {:.2}",
        s.quality.min_dihedral_deg,
        s.quality.mean_dihedral_deg,
        s.quality.max_dihedral_deg,
        s.quality.max_aspect,
        s.quality.mean_aspect
    );
    for m in &s.myomas {
        println!(
            "myoma {}: FIGO requested {:?}, placed {}, measured {} ({:.0} % intramural, {:.1} ml)",
            m.index,
            m.figo_requested,
            m.figo_placed,
            m.figo_measured,
            100.0 * m.intramural_fraction,
            m.volume_ml
        );
    }
    println!(
        "wrote uterus.vtu, summary.json, mesh.json to {}",
        out.display()
    );
    Ok(())
}
