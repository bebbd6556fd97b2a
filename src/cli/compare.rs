//! `canopy compare`: mean FLIP and percentiles between two images, optionally by pixel
//! class and with the error map.

use std::path::PathBuf;

use anyhow::Context as _;

#[derive(clap::Args)]
pub struct CompareArgs {
    a: PathBuf,
    b: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Also write the FLIP error map (magma colours) to this PNG.
    #[arg(long)]
    diff: Option<PathBuf>,
    /// Split the error by pixel class, from an image of A's classes (`render --method
    /// geometry --pixel-classes`, same camera and size), with B's mean linear
    /// luminance over A's in each class.
    #[arg(long)]
    classes: Option<PathBuf>,
}

pub fn compare(args: CompareArgs) -> anyhow::Result<()> {
    let CompareArgs {
        a,
        b,
        json,
        diff,
        classes,
    } = args;
    let compared = crate::metrics::compare_files(&a, &b)?;
    let r = &compared.result;
    if let Some(d) = &diff {
        let img = image::DynamicImage::ImageRgb8(r.error_image()).to_rgba8();
        crate::imageio::save_png(d, &img)?;
    }
    let by_class = match &classes {
        Some(path) => {
            let mask = crate::metrics::load_rgb(path)?;
            Some(crate::metrics::by_class(
                r,
                &compared.reference,
                &compared.test,
                &mask,
            )?)
        }
        None => None,
    };
    let s = r.stats;
    if json {
        #[derive(serde::Serialize)]
        struct Json<'a> {
            #[serde(flatten)]
            stats: crate::metrics::FlipStats,
            #[serde(skip_serializing_if = "Option::is_none")]
            classes: Option<&'a [crate::metrics::ClassFlip]>,
        }
        let j = Json {
            stats: s,
            classes: by_class.as_deref(),
        };
        println!("{}", serde_json::to_string(&j).context("encoding JSON")?);
    } else {
        println!(
            "FLIP {} vs {}: mean {:.4}, p50 {:.4}, p90 {:.4}, p99 {:.4}, max {:.4}",
            a.display(),
            b.display(),
            s.mean,
            s.p50,
            s.p90,
            s.p99,
            s.max
        );
        for c in by_class.iter().flatten() {
            println!(
                "  {:<11} {:>5.1} % of pixels, mean {:.4}, p90 {:.4}, share of the error {:>5.1} %, \
                 luminance {:.3} of A's",
                c.class.name(),
                c.pixel_fraction * 100.0,
                c.stats.mean,
                c.stats.p90,
                c.error_share * 100.0,
                c.luminance_ratio()
            );
        }
    }
    Ok(())
}
