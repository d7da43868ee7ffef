//! `lightfarm compare A.json B.json`: relative L2 error of A's indirect against B's over the
//! texels both hold, and the 95th-percentile texel error. Last line:
//! `relative_l2=<x> p95=<y>`.

use std::path::Path;

use lightfarm_proto::result::{compare, ResultFile};

use super::read_text;

pub fn run(a: &Path, b: &Path) -> anyhow::Result<()> {
    let load = |p: &Path| -> anyhow::Result<ResultFile> {
        serde_json::from_str(&read_text(p)?).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
    };
    let (ours, reference) = (load(a)?, load(b)?);
    let c = compare(&ours, &reference);
    if c.matched == 0 {
        anyhow::bail!("{} and {} share no texels", a.display(), b.display());
    }
    println!(
        "matched_texels={} unmatched_texels={}",
        c.matched, c.unmatched
    );
    println!("relative_l2={:.6} p95={:.6}", c.relative_l2, c.p95);
    Ok(())
}
