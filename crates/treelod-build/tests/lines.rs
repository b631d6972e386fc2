//! Branch lines (Clasen et al. 2011, spec §6.9) through the whole build: the demo tree's bark
//! skeleton follows its tubes and stays connected, every cell's hierarchy passes `verify`, the
//! lines' occlusion lies between their segments', builds are identical whatever the thread count,
//! bad settings are refused, and the shared models build (`--ignored` for the large ones).

use std::path::PathBuf;

use glam::Vec3;
use treelod_build::{
    AoConfig, BuildConfig, BuildError, BuildOutput, DemoTreeConfig, LineConfig, Placed, build_block, demo_tree,
    import_gltf,
};
use treelod_format::{Compression, Container, LineRecord, SectionKind};

fn with_lines() -> BuildConfig {
    BuildConfig { lines: Some(LineConfig::default()), ..BuildConfig::default() }
}

fn build(scene: &treelod_build::scene::Scene, config: &BuildConfig) -> (BuildOutput, Vec<u8>) {
    let out = build_block("t", &[Placed { scene, translation: Vec3::ZERO }], config, "t").expect("builds");
    let bytes = out.data.to_bytes(Compression::default()).expect("writes");
    (out, bytes)
}

/// Distance from `p` to the segment `a`–`b`.
fn to_segment(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    p.distance(a + t * ab)
}

fn ends(l: &LineRecord) -> (Vec3, Vec3) {
    (Vec3::from_array(l.p0), Vec3::from_array(l.p1))
}

#[test]
fn the_demo_tree_s_skeleton_follows_its_tubes_and_its_cells_verify() {
    let scene = demo_tree(&DemoTreeConfig::default());
    let (out, bytes) = build(&scene, &with_lines());
    let container = Container::from_bytes(&bytes).expect("opens");
    treelod_format::verify(&container).expect("verifies: the exact cut of every cell's lines");
    let lines = container.lines();
    assert_eq!(lines.len() as u64, out.stats.lines);
    // A line drawn at several consecutive levels is one record, counted at each level.
    assert!(out.stats.lines_per_level.iter().map(|&c| u64::from(c)).sum::<u64>() >= out.stats.lines);
    assert_eq!(u64::from(out.stats.lines_per_level[0]), out.stats.line_segments);
    assert!(lines.iter().all(|l| l.flags == 0 && l.leaf_count >= 1));
    assert_eq!(container.cells().last().expect("block cell").lines.count, 0, "lines live in the grid cells");

    // Level 0 (lo = 0, one segment each): the skeleton. The demo tree has 1 + 5 + 15 + 45 tubes.
    let segments: Vec<&LineRecord> = lines.iter().filter(|l| l.lo == 0.0 && l.leaf_count == 1).collect();
    assert_eq!(segments.len() as u64, out.stats.line_segments);
    assert!(segments.len() >= 66, "{} segments for 66 tubes", segments.len());
    // The trunk: the thickest segment stands upright at the base, on the y axis, about 0.2 m
    // thick (the demo's base radius 0.05 · 4 m, tapering to 0.08 at 4 m, bending a little).
    let trunk = segments.iter().max_by(|a, b| a.r0.max(a.r1).total_cmp(&b.r0.max(b.r1))).expect("segments");
    let (a, b) = ends(trunk);
    let low = if a.y < b.y { a } else { b };
    assert!(low.y < 1.0, "trunk segment {a}–{b}");
    assert!(Vec3::new(low.x, 0.0, low.z).length() < 0.1, "trunk segment {a}–{b} off the axis");
    assert!((b - a).normalize().y.abs() > 0.9, "trunk segment {a}–{b} not upright");
    let r = trunk.r0.max(trunk.r1);
    assert!((0.12..=0.22).contains(&r), "trunk radius {r}");
    // Connected: every segment starts on (within its parent's radius of) another segment, except
    // the trunk's base.
    let mut loose = Vec::new();
    for (i, s) in segments.iter().enumerate() {
        let (p0, _) = ends(s);
        if p0.y < 0.3 {
            continue;
        }
        let near = segments.iter().enumerate().filter(|&(j, _)| j != i).any(|(_, o)| {
            let (a, b) = ends(o);
            to_segment(p0, a, b) <= 1.5 * o.r0.max(o.r1) + 0.02
        });
        if !near {
            loose.push(p0);
        }
    }
    assert!(loose.is_empty(), "{} segments start on no other: {loose:?}", loose.len());
    // Every segment lies inside the bark: within its radius of the demo's tubes' axes is not
    // known here, but its ends are inside the tree's bounds and its radius below the trunk's.
    assert!(segments.iter().all(|s| s.r0 <= r + 1e-6 && s.r1 <= r + 1e-6));

    // Coarser levels hold fewer lines, and the coarsest are drawn out to infinity.
    let levels = &out.stats.lines_per_level;
    assert!(levels.len() >= 3, "{levels:?}");
    assert!(levels.windows(2).all(|w| w[1] < w[0]), "{levels:?}");
    assert!(lines.iter().any(|l| l.hi == f32::INFINITY));
    let keys: Vec<&str> = container.metadata().settings.iter().map(|s| s.key.as_str()).collect();
    assert!(keys.iter().any(|k| k.starts_with("lines.")), "{keys:?}");

    // Without the option: no lines.
    let (plain, _) = build(&scene, &BuildConfig::default());
    assert!(plain.data.lines.is_empty() && plain.stats.lines == 0 && plain.data.line_ao.is_empty());
}

/// The far lines (spec §6.9.1) merge the cells' lines across cells down to one line per tree,
/// and take over where they draw exactly the lines the cells draw, with no cell fading between
/// levels: the switch does not show.
#[test]
fn the_far_lines_take_over_where_they_draw_the_cells_lines() {
    use treelod_build::lines::{FAR_BLEND, FAR_TAKEOVER};
    let scene = demo_tree(&DemoTreeConfig::default());
    let (out, bytes) = build(&scene, &with_lines());
    let container = Container::from_bytes(&bytes).expect("opens");
    let (lines, far) = (container.lines(), container.far_lines());
    assert!(!far.is_empty(), "the demo tree's lines merge across cells");
    treelod_format::check_spt(SectionKind::FAR_LINES, 0, 0, far).expect("one exact-cut hierarchy");
    let levels = &out.stats.far_lines_per_level;
    assert!(levels.windows(2).all(|w| w[1] < w[0]) && levels.last() == Some(&1), "one line for one tree: {levels:?}");
    let coarsest = lines.iter().filter(|l| l.hi == f32::INFINITY).count();
    assert!(*levels.last().unwrap() < coarsest as u32, "fewer far lines than the cells' coarsest {coarsest}");

    // The switch, half an octave below τ_far (where far level 0 ends): no cell fades there under
    // the reference blend.
    let switch = treelod_format::far_switch(far);
    assert!(switch.is_finite());
    let half = (0.5 * FAR_BLEND).exp2();
    for l in lines.iter().filter(|l| l.lo > 0.0) {
        assert!(!(l.lo / half <= switch && switch < l.lo * half), "a cell fades at the switch {switch}: {l:?}");
    }
    let drawn = |records: &[LineRecord]| {
        let mut v: Vec<[u32; 9]> = records
            .iter()
            .filter(|l| l.lo <= switch && switch < l.hi)
            .map(|l| {
                let f = |x: f32| x.to_bits();
                [f(l.p0[0]), f(l.p0[1]), f(l.p0[2]), f(l.r0), f(l.p1[0]), f(l.p1[1]), f(l.p1[2]), f(l.r1), l.color]
            })
            .collect();
        v.sort_unstable();
        v
    };
    let (cells, far_drawn) = (drawn(lines), drawn(far));
    assert_eq!(cells, far_drawn, "at the switch the far lines are the cells' lines");
    assert_eq!(far_drawn.len() as u32, levels[0], "far level 0");
    assert!(far_drawn.len() as f32 <= FAR_TAKEOVER * coarsest as f32, "taken over once the cells are nearly merged");
    // Inside the block's bounds.
    let (min, max) = (Vec3::from_array(container.block().bounds_min), Vec3::from_array(container.block().bounds_max));
    for l in far {
        let (a, b) = ends(l);
        assert!(a.cmpge(min).all() && a.cmple(max).all() && b.cmpge(min).all() && b.cmple(max).all(), "{l:?}");
    }
}

#[test]
fn a_line_s_occlusion_lies_between_its_segments() {
    let scene = demo_tree(&DemoTreeConfig { leaves: 1500, ..DemoTreeConfig::default() });
    let config = BuildConfig { ao: Some(AoConfig { rays: 8, ..AoConfig::default() }), ..with_lines() };
    let (_, bytes) = build(&scene, &config);
    let container = Container::from_bytes(&bytes).expect("opens");
    treelod_format::verify(&container).expect("verifies");
    // FAR_LINES and FAR_LINE_AO are kinds of 1.9; the points' facing (POINT_FACING, which every
    // build writes) makes the file 1.14.
    assert_eq!((SectionKind::FAR_LINES.since_minor(), SectionKind::FAR_LINE_AO.since_minor()), (9, 9));
    assert_eq!(container.header().minor, 14, "POINT_FACING is a kind of 1.14");
    assert_eq!(container.far_line_ao().len(), container.far_lines().len(), "one byte per far line");
    let (lines, ao) = (container.lines(), container.line_ao());
    assert_eq!(ao.len(), lines.len(), "one byte per line");
    let mut merged = 0;
    let mut values = Vec::new();
    for cell in container.cells() {
        let range = cell.lines.as_usize();
        let (records, values_of) = (&lines[range.clone()], &ao[range]);
        let n = records.iter().map(|l| (l.leaf_first + l.leaf_count) as usize).max().unwrap_or(0);
        let mut by_segment = vec![None; n];
        for (l, &a) in records.iter().zip(values_of) {
            if l.lo == 0.0 && l.leaf_count == 1 {
                by_segment[l.leaf_first as usize] = Some(a);
            }
        }
        assert!(by_segment.iter().all(Option::is_some), "every segment has its level-0 line");
        values.extend(by_segment.iter().flatten().copied());
        for (l, &a) in records.iter().zip(values_of) {
            let run = &by_segment[l.leaf_first as usize..(l.leaf_first + l.leaf_count) as usize];
            let lo = run.iter().flatten().min().copied().expect("a segment");
            let hi = run.iter().flatten().max().copied().expect("a segment");
            assert!(lo <= a && a <= hi, "line of segments {}+{}: {a} outside {lo}..={hi}", l.leaf_first, l.leaf_count);
            merged += usize::from(l.leaf_count > 1);
        }
    }
    assert!(merged > 10, "{merged} merged lines");
    // The bark is occluded more inside the crown than at the trunk's base: the values spread.
    let (min, max) = (values.iter().min().copied().unwrap_or(0), values.iter().max().copied().unwrap_or(0));
    assert!(max - min > 40, "{min}..={max}");
}

#[test]
fn line_builds_are_identical_whatever_the_thread_count() {
    let scene = demo_tree(&DemoTreeConfig { leaves: 300, ..DemoTreeConfig::default() });
    let bytes_with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| {
            let config = BuildConfig { ao: Some(AoConfig { rays: 4, ..AoConfig::default() }), ..with_lines() };
            let (out, bytes) = build(&scene, &config);
            assert!(out.stats.lines > 66);
            assert_eq!(out.data.line_ao.len() as u64, out.stats.lines);
            bytes
        })
    };
    assert_eq!(bytes_with(1), bytes_with(4));
}

#[test]
fn bad_line_settings_are_refused_naming_the_setting() {
    let scene = demo_tree(&DemoTreeConfig { leaves: 50, ..DemoTreeConfig::default() });
    let trees = [Placed { scene: &scene, translation: Vec3::ZERO }];
    let cases: [(LineConfig, &str); 6] = [
        (LineConfig { pixels: 0.0, ..LineConfig::default() }, "pixels"),
        (LineConfig { pixels: f32::NAN, ..LineConfig::default() }, "pixels"),
        (LineConfig { candidates: 0, ..LineConfig::default() }, "candidates"),
        (LineConfig { resolution: 100, ..LineConfig::default() }, "resolution"),
        (LineConfig { views: 0, ..LineConfig::default() }, "views"),
        (LineConfig { views: 17, ..LineConfig::default() }, "views"),
    ];
    for (lines, field) in cases {
        let config = BuildConfig { lines: Some(lines), ..BuildConfig::default() };
        match build_block("t", &trees, &config, "t") {
            Err(e @ BuildError::Setting { .. }) => assert!(e.to_string().contains(field), "{field}: {e}"),
            other => panic!("{field}: expected a setting error, got {:?}", other.map(|o| o.stats)),
        }
    }
}

fn model(name: &str) -> PathBuf {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/assets/trees").join(name);
    assert!(path.exists(), "{} is missing: the repository is checked out with ../shared beside it", path.display());
    path
}

/// Builds a shared model with lines, verifies it, and prints the line stage's numbers.
fn build_model(name: &str) {
    let scene = import_gltf(&model(name)).expect("imports");
    let (out, bytes) = build(&scene, &BuildConfig { ao: None, ..with_lines() });
    let container = Container::from_bytes(&bytes).expect("opens");
    treelod_format::verify(&container).expect("verifies");
    let s = &out.stats;
    eprintln!(
        "{name}: {} skeleton segments, {} lines, per level {:?}, line stage {:.2} s",
        s.line_segments,
        s.lines,
        s.lines_per_level,
        s.stage_millis("lines") as f64 / 1000.0
    );
    assert!(s.line_segments > 0 && s.lines >= s.line_segments);
}

#[test]
fn the_oak_and_the_low_poly_tree_build_lines_that_verify() {
    build_model("ez-tree-oak-large-23k.glb");
    build_model("quaternius-common-tree-1-3k.glb");
}

#[test]
#[ignore = "tens of seconds in release: cargo nextest run --release -p treelod-build --run-ignored all lines_of"]
fn lines_of_every_shared_model() {
    for name in [
        "ez-tree-pine-large-19k.glb",
        "plantcatalog-hk-orchid-tree-31k.glb",
        "polyhaven-jacaranda-tree-55k.glb",
        "sapling-weeping-willow-154k.glb",
        "sapling-japanese-maple-669k.glb",
    ] {
        build_model(name);
    }
}
