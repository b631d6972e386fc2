//! tmp
#[test]
fn tmp_probe_lines() {
    for m in ["/tmp/s28/oak.treelod"] {
        let c = treelod_format::Container::open(std::path::Path::new(m)).unwrap();
        let b = c.block();
        let height = b.bounds_max[1] - b.bounds_min[1];
        let lines = c.lines();
        let mut los: Vec<(f32, u32)> = Vec::new();
        for (i, cell) in c.cells().iter().enumerate() {
            let r = cell.lines;
            let recs = &lines[r.first as usize..(r.first + r.count) as usize];
            let roots: Vec<_> = recs.iter().filter(|l| l.hi.is_infinite()).collect();
            if roots.is_empty() {
                continue;
            }
            let lo = roots.iter().map(|l| l.lo).fold(0f32, f32::max);
            los.push((lo, roots.len() as u32));
            eprintln!(
                "cell {i}: {} lines, {} roots, coarsest from {lo:.3} ({:.1} px)",
                recs.len(),
                roots.len(),
                height / lo
            );
        }
        let far = c.far_lines();
        eprintln!("far {} records; levels lo values: {:?}", far.len(), {
            let mut v: Vec<f32> = far.iter().map(|l| l.lo).collect();
            v.sort_by(f32::total_cmp);
            v.dedup();
            v.iter().map(|x| height / x).collect::<Vec<_>>()
        });
    }
}
