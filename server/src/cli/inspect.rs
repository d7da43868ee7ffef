//! `lightfarm inspect BUNDLE`: what a bundle holds, section by section and operator by
//! operator (sizes, ranks, values), for people sizing a bake.

use std::path::PathBuf;

use anyhow::Context;
use lightfarm_proto::bundle::{Bundle, DeltaSource, Matrix, TransportOps};

/// Values and count of a group of matrices.
#[derive(Default)]
struct Tally {
    matrices: usize,
    values: usize,
}

impl Tally {
    fn add(&mut self, m: &Matrix) {
        self.matrices += 1;
        self.values += m.data.len();
    }
}

pub fn run(path: PathBuf) -> anyhow::Result<()> {
    let bytes = std::fs::read(&path).with_context(|| format!("cannot read {}", path.display()))?;
    let bundle = Bundle::decode(&bytes).with_context(|| format!("{}", path.display()))?;
    crate::say!(
        "{}: {} bytes, {} texels, {} blocks, {} shapes",
        path.display(),
        bytes.len(),
        bundle.layout.n_texels(),
        bundle.blocks.len(),
        bundle.shapes.len()
    );
    let (mut u_b, mut t_db, mut u_r) = (Tally::default(), Tally::default(), Tally::default());
    for (k, s) in bundle.shapes.iter().enumerate() {
        let users = bundle.blocks.iter().filter(|b| b.shape as usize == k);
        let (blocks, turned) = users.fold((0, 0), |(n, t), b| {
            (n + 1, t + usize::from(b.symmetry.is_some()))
        });
        u_b.add(&s.u_b);
        t_db.add(&s.t_db);
        for o in &s.openings {
            u_r.add(&o.u_r);
        }
        let q: Vec<u32> = s.openings.iter().map(|o| o.u_r.cols).collect();
        crate::say!(
            "  shape {}: {} texels, rank {}, opening ranks {q:?}, {blocks} blocks ({turned} rotated or mirrored)",
            &s.key[..s.key.len().min(12)],
            s.u_b.rows,
            s.u_b.cols
        );
    }
    let (mut transport, mut bases) = (Tally::default(), Tally::default());
    match &bundle.transport {
        Some(TransportOps::Lightfield(e)) => e.iter().for_each(|e| transport.add(&e.matrix)),
        Some(TransportOps::Traced(e)) => e.iter().for_each(|e| transport.add(&e.matrix)),
        Some(TransportOps::Compact(e)) => e.iter().for_each(|e| {
            transport.add(&e.y);
            transport.add(&e.z);
        }),
        Some(TransportOps::Factored(f)) => {
            f.bases.iter().for_each(|b| bases.add(&b.q));
            f.entries.iter().for_each(|e| {
                transport.add(&e.y);
                transport.add(&e.z);
            })
        }
        None => {}
    }
    let line = |name: &str, t: &Tally| {
        crate::say!(
            "  {name:<28} {:>6} matrices {:>10} values",
            t.matrices,
            t.values
        )
    };
    line("U_b", &u_b);
    line("T_d→b", &t_db);
    line("U_r (openings)", &u_r);
    line("transport", &transport);
    line("transport source bases", &bases);
    if let Some(d) = &bundle.drt {
        let mut t_dc = Tally::default();
        d.clutter.iter().for_each(|c| t_dc.add(&c.t_dc));
        let (mut from_block, mut from_clutter, mut from_direct) =
            (Tally::default(), Tally::default(), Tally::default());
        for e in &d.entries {
            let tally = match e.source {
                DeltaSource::Block(_) => &mut from_block,
                DeltaSource::Clutter(_) => &mut from_clutter,
                DeltaSource::Direct { .. } => &mut from_direct,
            };
            tally.add(&e.matrix);
            if let Some(mix) = &e.mix {
                // Low-rank entry: its right factor is one more matrix of the same source.
                tally.add(mix);
            }
        }
        line("T_d→c", &t_dc);
        line("ΔU_b and C_b (from blocks)", &from_block);
        line("ΔU_c (from clutter)", &from_clutter);
        line("exact gather (low rank)", &from_direct);
        if let Some(g) = &d.direct_gather {
            crate::say!(
                "  {:<28} {:>6} rows     {:>10} values",
                "exact clutter gather",
                g.rows.len(),
                g.values.len()
            );
        }
    }
    if let Some(p) = &bundle.probes {
        let mut probes = Tally::default();
        p.entries.iter().for_each(|e| {
            probes.add(&e.matrix);
            if let Some(mix) = &e.mix {
                probes.add(mix);
            }
        });
        line(&format!("probes ({})", p.n_probes), &probes);
    }
    for g in bundle.dnrt.as_deref().unwrap_or(&[]) {
        crate::say!(
            "  {:<28} {:>17} bytes",
            format!("dnrt grid \"{}\"", g.object),
            g.data_bytes()
        );
    }
    for s in &bundle.dynamic_shapes {
        crate::say!(
            "  {:<28} {:>6} triangles",
            format!("shape of \"{}\"", s.object),
            s.triangles.len()
        );
    }
    if let Some(sh) = &bundle.sh {
        let (mut from_block, mut from_clutter) = (Tally::default(), Tally::default());
        for e in &sh.entries {
            let t = match e.source {
                DeltaSource::Block(_) => &mut from_block,
                // Validation refuses direct-light sources in SH entries.
                DeltaSource::Clutter(_) | DeltaSource::Direct { .. } => &mut from_clutter,
            };
            t.add(&e.y);
            t.add(&e.z);
        }
        line("SH responses (from blocks)", &from_block);
        line("SH responses (from clutter)", &from_clutter);
    }
    if let Some(f) = &bundle.full {
        crate::say!("  {:<28} {:>17} values", "full (sparse)", f.values.len());
    }
    Ok(())
}
