//! GPU selection with the policy on the Vulkan backend (Mesa lavapipe in CI): in a forest of a
//! calibrated container, the CPU assigns the trees and draws every technique but the point tree,
//! the octahedral impostor and the billboards, the GPU selects the point tree's trees and appends
//! the impostors' and billboards' quads and nothing else, on the same share of the transition
//! dither as the CPU path, and the image is the CPU path's.

mod common;

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use common::{BACKGROUND, assert_same_selection, calibrated_demo_without_octahedral, differing};
use glam::{Mat4, Vec3, vec3};
use treelod_format::Container;
use treelod_render::offscreen::{Gpu, Image, render_image};
use treelod_render::{Camera, DrawSource, GpuDraw, Instance, Policy, Renderer, Settings, Technique};
use treelod_runtime::{DrawRange, ModelLod};

/// The adapter, with the count feature the GPU selection tests expect of lavapipe.
fn gpu() -> Gpu {
    let gpu = common::gpu();
    assert!(gpu.device.features().contains(wgpu::Features::MULTI_DRAW_INDIRECT_COUNT));
    gpu
}

/// 48 trees: 8 rows from 6 m to about 250 m ahead, 6 across each, spread with the distance so
/// that each row spans the view; from a few pixels to most of the screen.
fn positions(lod: &ModelLod) -> Vec<Vec3> {
    let centre = lod.centre();
    let mut positions = Vec::new();
    for row in 0..8 {
        let d = 6.0 * 1.7f32.powi(row);
        for column in 0..6 {
            let x = (column as f32 - 2.5) * 0.16 * d + if row % 2 == 0 { 0.0 } else { 0.05 * d };
            positions.push(vec3(x, -centre.y, -d) - vec3(centre.x, 0.0, centre.z));
        }
    }
    positions
}

/// The calibrated demo tree, its point tree and the 48 trees' [`positions`].
fn demo_forest() -> (Arc<Container>, ModelLod, Vec<Vec3>) {
    let container = calibrated_demo_without_octahedral();
    let lod = ModelLod::from_container(&container);
    let positions = positions(&lod);
    (container, lod, positions)
}

/// A renderer of `container` at `positions`, selecting on the GPU if `on_gpu`.
fn renderer(gpu: &Gpu, container: &Arc<Container>, settings: Settings, positions: &[Vec3], on_gpu: bool) -> Renderer {
    // Everything streams in the first frame, so the CPU path draws its selection unclamped.
    let settings = Settings { upload_budget: 1 << 30, ..settings };
    let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), settings);
    let model = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(container)).expect("model");
    if on_gpu {
        renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("fits");
    }
    let instances: Vec<Instance> =
        positions.iter().map(|&p| Instance { model, transform: Mat4::from_translation(p) }).collect();
    renderer.set_instances(&instances);
    renderer
}

/// The techniques drawn through the point tree's selection (no pruning in these containers).
fn point_tree(technique: Technique) -> bool {
    matches!(technique, Technique::Spt | Technique::Full)
}

/// The CPU path's point-tree ranges with the instance indices of the renderer's list: the
/// selection runs over the point tree's trees in ascending order (all of them: no remapping).
fn cpu_point_tree_ranges(cpu: &Renderer) -> Vec<DrawRange> {
    let list: Vec<u32> =
        (0u32..).zip(cpu.instance_techniques()).filter(|&(_, &t)| point_tree(t)).map(|(i, _)| i).collect();
    cpu.selection().ranges().iter().map(|r| DrawRange { instance: list[r.instance as usize], ..*r }).collect()
}

/// Two views of the forest: from the ground at the first row, and from above behind it.
fn cameras() -> [(&'static str, Camera); 2] {
    [
        ("ahead", Camera::look_at(vec3(0.0, 2.0, 4.0), vec3(0.0, 2.0, -100.0), 0.9, 256, 256)),
        ("above", Camera::look_at(vec3(-20.0, 40.0, 30.0), vec3(5.0, 0.0, -120.0), 0.9, 256, 256)),
    ]
}

fn gpu_draws(gpu: &Gpu, renderer: &Renderer) -> Vec<GpuDraw> {
    renderer.read_gpu_draws(&gpu.device, &gpu.queue).expect("reads back").expect("the GPU selected")
}

/// With the policy, the hybrid frame assigns the trees as the CPU frame does, the GPU selects
/// exactly the CPU's point-tree ranges (as sets, up to rounding at thresholds) and no range of a
/// tree assigned another technique, the CPU records the other techniques' draws, the image is
/// the CPU path's, and the statistics, once the GPU's counts are read back, are the CPU's.
#[test]
fn policy_frames_select_the_point_tree_s_trees_on_the_gpu() {
    let gpu = gpu();
    let (container, lod, positions) = demo_forest();
    // No transition, no occlusion: the frames repeat (the GPU's counts arrive a frame or two
    // later).
    let policy = Policy { transition: 0, occlusion: false, ..Policy::default() };
    let settings = Settings { policy: Some(policy), ..Settings::default() };
    let mut cpu = renderer(&gpu, &container, settings, &positions, false);
    let mut hybrid = renderer(&gpu, &container, settings, &positions, true);
    let mut others_seen = BTreeSet::new();
    for (name, camera) in cameras() {
        let (a, cpu_stats) = render_image(&gpu, &mut cpu, &camera, BACKGROUND).expect("renders");
        let (b, stats) = render_image(&gpu, &mut hybrid, &camera, BACKGROUND).expect("renders");
        assert!(!cpu_stats.gpu_selection && stats.gpu_selection, "{name}: {stats:?}");
        assert_eq!(cpu_stats.ranges_clamped, 0, "{name}: everything streamed");
        let techniques = cpu.instance_techniques().to_vec();
        assert_eq!(hybrid.instance_techniques(), techniques, "{name}: the same assignment");
        eprintln!("{name}: {:?}", cpu_stats.instances);

        // The GPU's ranges are the CPU's point-tree ranges, of exactly the point tree's trees.
        let draws = gpu_draws(&gpu, &hybrid);
        let ranges: Vec<DrawRange> = draws.iter().map(|d| d.range).collect();
        let reference = cpu_point_tree_ranges(&cpu);
        assert!(!reference.is_empty(), "{name}: some tree is drawn with the point tree");
        let tolerated = assert_same_selection(name, &reference, &ranges, &lod);
        assert!(tolerated * 100 <= reference.len(), "{name}: {tolerated} ranges at a threshold");
        let on_gpu: BTreeSet<u32> = ranges.iter().map(|r| r.instance).collect();
        let in_cpu: BTreeSet<u32> = reference.iter().map(|r| r.instance).collect();
        assert_eq!(on_gpu, in_cpu, "{name}: the trees the GPU draws");
        for d in &draws {
            let t = techniques[d.range.instance as usize];
            assert!(point_tree(t), "{name}: the GPU drew tree {} assigned {t}: {d:?}", d.range.instance);
            assert_eq!((d.technique, d.dither), (t, [0.0, 1.0]), "{name}: {d:?}");
        }
        // The other techniques are the CPU's draws, the same in both paths, but the billboards'
        // quads, which the GPU appends as the CPU path records them.
        let others = |r: &Renderer| -> Vec<_> {
            r.draws().iter().map(|d| (d.instance, d.source, d.count, d.technique, d.tau_points)).collect()
        };
        let cpu_others = others(&cpu).into_iter().filter(|d| !point_tree(d.3) && d.1 != DrawSource::Billboards);
        assert_eq!(others(&hybrid), cpu_others.collect::<Vec<_>>());
        assert!(
            hybrid
                .draws()
                .iter()
                .all(|d| !matches!(d.source, DrawSource::Points | DrawSource::Roots | DrawSource::Billboards))
        );
        let billboards = cpu_quads_of(&cpu, DrawSource::Billboards);
        assert_eq!(gpu_quads_of(&gpu, &hybrid, DrawSource::Billboards), billboards, "{name}: the billboards");
        others_seen.extend(hybrid.draws().iter().map(|d| d.technique));
        others_seen.extend(billboards.iter().map(|q| q.2));

        let (diff, covered) = differing(&a, &b);
        common::keep(&a, &format!("gpu-policy-{name}-cpu"));
        common::keep(&b, &format!("gpu-policy-{name}-hybrid"));
        eprintln!("{name}: {diff} of {covered} covered pixels differ, {tolerated} ranges at a threshold");
        assert!(covered > 500, "{name}: the forest is in view");
        assert!(diff * 200 <= covered, "{name}: {diff} of {covered} pixels differ");

        // The same frame again, until the GPU's counts of it are read back: the CPU's.
        let mut again = stats;
        for _ in 0..10 {
            gpu.device.poll(wgpu::PollType::wait_indefinitely()).expect("polls");
            again = hybrid.prepare(&gpu.device, &gpu.queue, &camera);
            if again.instances_visible == cpu_stats.instances_visible {
                break;
            }
        }
        assert_eq!(hybrid.instance_techniques(), techniques, "{name}: the assignment holds");
        assert_eq!(again.instances, cpu_stats.instances, "{name}: {again:?}");
        assert_eq!(again.leaving, 0);
        if tolerated == 0 {
            assert_eq!(again.submitted, cpu_stats.submitted, "{name}");
            assert_eq!(again.by_technique, cpu_stats.by_technique, "{name}");
            assert_eq!(again.ranges, cpu_stats.ranges, "{name}");
        }
    }
    assert!(others_seen.iter().any(|&t| !point_tree(t)), "the CPU drew other techniques: {others_seen:?}");
}

/// A tree the policy draws with another technique, alone: the GPU draws nothing (its buckets'
/// counts are 0) and the CPU's draws still show, as in the CPU path's image.
#[test]
fn a_frame_the_gpu_draws_nothing_of_shows_the_cpu_s_draws() {
    let gpu = gpu();
    let (container, _, positions) = demo_forest();
    let camera = Camera::look_at(vec3(0.0, 2.0, 4.0), vec3(0.0, 2.0, -100.0), 0.9, 128, 128);
    let mut forest = renderer(&gpu, &container, Settings::default(), &positions, false);
    forest.prepare(&gpu.device, &gpu.queue, &camera);
    let (i, technique) = forest
        .instance_techniques()
        .iter()
        .enumerate()
        .find(|&(i, &t)| !point_tree(t) && i >= 6)
        .map(|(i, &t)| (i, t))
        .expect("a tree drawn with another technique");
    let one = [positions[i]];
    let mut cpu = renderer(&gpu, &container, Settings::default(), &one, false);
    let mut hybrid = renderer(&gpu, &container, Settings::default(), &one, true);
    let (a, _) = render_image(&gpu, &mut cpu, &camera, BACKGROUND).expect("renders");
    let (b, stats) = render_image(&gpu, &mut hybrid, &camera, BACKGROUND).expect("renders");
    assert!(stats.gpu_selection && hybrid.instance_techniques() == [technique], "{stats:?}");
    assert!(gpu_draws(&gpu, &hybrid).is_empty(), "the GPU draws nothing");
    let (diff, covered) = differing(&a, &b);
    assert!(covered > 50, "tree {i} ({technique}) is drawn: {covered} pixels");
    assert_eq!(diff, 0, "tree {i} ({technique}): {diff} of {covered} pixels differ");
}

/// Per instance, the (technique, dither) of its point-tree draws.
type Fades = BTreeMap<u32, BTreeSet<(Technique, [u32; 2])>>;

/// A renderer of the forest on the CPU path and one with GPU selection, both with a policy of
/// `target` whose transitions take 4 frames (no hysteresis, no occlusion measurement), for the
/// flights below.
fn fading_renderers(gpu: &Gpu, container: &Arc<Container>, positions: &[Vec3], target: f32) -> (Renderer, Renderer) {
    let policy = Policy { target, hysteresis: 0.0, transition: 4, occlusion: false, ..Policy::default() };
    let settings = Settings { policy: Some(policy), ..Settings::default() };
    (renderer(gpu, container, settings, positions, false), renderer(gpu, container, settings, positions, true))
}

/// The camera of a flight into the forest along -z, `step` units a frame.
fn flight_camera(frame: usize, step: f32) -> Camera {
    let z = 10.0 - step * frame as f32;
    Camera::look_at(vec3(1.0, 2.0, z), vec3(1.0, 2.0, z - 100.0), 0.9, 192, 192)
}

/// Frame `frame` of a flight (`step` units a frame) drawn by both renderers: the same
/// transitions and techniques per tree on both paths (`label` names the case in failures). The
/// images, CPU path first.
fn flight_frame(
    gpu: &Gpu,
    (cpu, hybrid): (&mut Renderer, &mut Renderer),
    frame: usize,
    step: f32,
    label: &str,
) -> (Image, Image) {
    let camera = flight_camera(frame, step);
    let (a, cpu_stats) = render_image(gpu, cpu, &camera, BACKGROUND).expect("renders");
    let (b, stats) = render_image(gpu, hybrid, &camera, BACKGROUND).expect("renders");
    assert_eq!(stats.transitions, cpu_stats.transitions, "{label}frame {frame}");
    assert_eq!(hybrid.instance_techniques(), cpu.instance_techniques(), "{label}frame {frame}");
    (a, b)
}

/// A flight frame's quad draws of one kind: each drawn by the GPU (`on_gpu`) or left to the CPU
/// (`kept`), never both, together the CPU path's (`expected`), and the two paths' images (CPU
/// first) within 1 % of their covered pixels of each other.
fn assert_quads_split(on_gpu: &Quads, kept: &Quads, expected: &Quads, (a, b): (&Image, &Image), label: &str) {
    assert!(on_gpu.is_disjoint(kept), "{label}: a tree's quads drawn twice");
    assert_eq!(&(on_gpu | kept), expected, "{label}: the quads' draws");
    let (diff, covered) = differing(a, b);
    assert!(diff * 100 <= covered, "{label}: {diff} of {covered} pixels differ");
}

/// A dither range in 1/65535ths, as the shader holds it.
fn unorm([lo, hi]: [f32; 2]) -> [u32; 2] {
    [(lo * 65535.0).round() as u32, (hi * 65535.0).round() as u32]
}

/// The camera flies into the forest with transitions of 4 frames: the point-tree draws of the
/// trees in a transition into or out of the point tree carry the same technique and share of
/// the dither on the GPU as on the CPU (a tree both entering and leaving the point tree, from the
/// full mesh to the point tree say, is drawn once on every pixel), and the images match.
#[test]
fn trees_fading_into_and_out_of_the_point_tree_fade_on_the_gpu_as_on_the_cpu() {
    let gpu = gpu();
    let (container, _, positions) = demo_forest();
    let (mut cpu, mut hybrid) = fading_renderers(&gpu, &container, &positions, Policy::DEFAULT_TARGET);
    let (mut fading_in, mut fading_out, mut max_diff) = (0, 0, 0.0f64);
    for frame in 0..16 {
        let (a, b) = flight_frame(&gpu, (&mut cpu, &mut hybrid), frame, 6.0, "");

        let mut expected = Fades::new();
        for d in cpu.draws() {
            if matches!(d.source, DrawSource::Triangles | DrawSource::Points | DrawSource::Roots) {
                expected.entry(d.instance).or_default().insert((d.technique, unorm(d.dither)));
            }
        }
        for (&i, set) in &mut expected {
            // Entering and leaving the point tree's selection: one draw on every pixel.
            if set.len() > 1 {
                let mut shares: Vec<[u32; 2]> = set.iter().map(|s| s.1).collect();
                shares.sort_unstable();
                assert!(shares.len() == 2 && shares[0][1] == shares[1][0], "frame {frame}, tree {i}: {set:?}");
                let goes_to = cpu.instance_techniques()[i as usize];
                *set = BTreeSet::from([(goes_to, [0, 65535])]);
            }
            let &(technique, share) = set.iter().next().expect("one");
            if share != [0, 65535] {
                if share[0] == 0 {
                    fading_in += 1;
                } else {
                    fading_out += 1;
                    assert!(!point_tree(cpu.instance_techniques()[i as usize]), "{technique}");
                }
            }
        }
        let mut got = Fades::new();
        for d in gpu_draws(&gpu, &hybrid) {
            got.entry(d.range.instance).or_default().insert((d.technique, unorm(d.dither)));
        }
        assert_eq!(got, expected, "frame {frame}: the point tree's trees, techniques and dither shares");

        let (diff, covered) = differing(&a, &b);
        max_diff = max_diff.max(diff as f64 / covered.max(1) as f64);
        assert!(diff * 100 <= covered, "frame {frame}: {diff} of {covered} pixels differ");
    }
    eprintln!("{fading_in} point-tree draws fading in, {fading_out} fading out, pixels differing ≤ {max_diff}");
    assert!(fading_in > 0 && fading_out > 0, "the flight has trees fading into and out of the point tree");
}

/// With the policy's occlusion (the default), the trees the GPU draws are measured as the CPU
/// path measures them: after a few frames every tree has the CPU path's visible fraction and
/// technique, some of the point tree's trees partly hidden.
#[test]
fn the_gpu_s_trees_are_measured_for_occlusion() {
    let gpu = gpu();
    let (container, _, positions) = demo_forest();
    assert!(Settings::default().policy.is_some_and(|p| p.occlusion), "the default");
    // Half the default target, so that the near trees, some of them hidden behind the nearest,
    // are drawn with the point tree: with the default the demo tree's tables put the LoD chain
    // within the target of the point tree from 32 pixels up, and nothing is.
    let settings = Settings { policy: Some(Policy { target: 0.005, ..Policy::default() }), ..Settings::default() };
    let mut cpu = renderer(&gpu, &container, settings, &positions, false);
    let mut hybrid = renderer(&gpu, &container, settings, &positions, true);
    let camera = Camera::look_at(vec3(0.0, 2.0, 4.0), vec3(0.0, 2.0, -100.0), 0.9, 192, 192);
    for _ in 0..4 {
        render_image(&gpu, &mut cpu, &camera, BACKGROUND).expect("renders");
        render_image(&gpu, &mut hybrid, &camera, BACKGROUND).expect("renders");
    }
    let (a, b) = (cpu.visible_fractions(), hybrid.visible_fractions());
    let techniques = cpu.instance_techniques();
    let hidden_point_trees = (0..a.len()).filter(|&i| point_tree(techniques[i]) && a[i] < 0.9).count();
    eprintln!("{hidden_point_trees} point-tree trees partly hidden: {a:?}");
    assert!(hidden_point_trees > 0, "some tree the GPU draws is partly hidden");
    for i in 0..a.len() {
        assert!((a[i] - b[i]).abs() < 0.05, "tree {i} ({}): cpu {}, hybrid {}", techniques[i], a[i], b[i]);
    }
    assert_eq!(hybrid.instance_techniques(), techniques);
}

/// Without a policy (the point tree forced) GPU selection selects every tree as before: the CPU
/// records nothing, every GPU draw covers every pixel under the point tree; a policy frame in
/// between does not leave its per-instance draws behind.
#[test]
fn frames_without_a_policy_select_every_tree_on_the_gpu() {
    let gpu = gpu();
    let (container, lod, positions) = demo_forest();
    let camera = Camera::look_at(vec3(0.0, 2.0, 4.0), vec3(0.0, 2.0, -100.0), 0.9, 128, 128);
    let forced = Settings::forced(Technique::Spt);
    let mut cpu = renderer(&gpu, &container, forced, &positions, false);
    let mut hybrid = renderer(&gpu, &container, forced, &positions, true);
    let check = |hybrid: &mut Renderer, cpu: &mut Renderer, what: &str| {
        cpu.prepare(&gpu.device, &gpu.queue, &camera);
        let stats = hybrid.prepare(&gpu.device, &gpu.queue, &camera);
        assert!(stats.gpu_selection && hybrid.draws().is_empty(), "{what}: {stats:?}");
        let draws = gpu_draws(&gpu, hybrid);
        assert!(draws.iter().all(|d| d.technique == Technique::Spt && d.dither == [0.0, 1.0]), "{what}");
        let ranges: Vec<DrawRange> = draws.iter().map(|d| d.range).collect();
        assert_same_selection(what, cpu.selection().ranges(), &ranges, &lod);
        ranges.iter().map(|r| r.instance).collect::<BTreeSet<u32>>().len()
    };
    let all = check(&mut hybrid, &mut cpu, "forced");
    // A policy frame draws fewer trees on the GPU; forced again, every tree is back.
    hybrid.settings_mut().policy = Some(Policy::default());
    hybrid.prepare(&gpu.device, &gpu.queue, &camera);
    let policy_trees = gpu_draws(&gpu, &hybrid).iter().map(|d| d.range.instance).collect::<BTreeSet<u32>>().len();
    assert!(policy_trees < all, "the policy draws some trees with other techniques ({policy_trees} of {all})");
    hybrid.settings_mut().policy = None;
    assert_eq!(check(&mut hybrid, &mut cpu, "forced again"), all);
}

/// The calibrated demo tree with its octahedral impostor, which the policy draws every tree
/// below about 100 pixels with (one quad each), and the 48 trees' [`positions`].
fn octahedral_forest() -> (Arc<Container>, Vec<Vec3>) {
    let container = common::calibrated_demo();
    assert!(!container.octahedral().is_empty(), "the demo tree has its octahedral impostor");
    let positions = positions(&ModelLod::from_container(&container));
    (container, positions)
}

/// A frame's octahedral impostor (or billboard) draws as (instance, quads, technique, dither in
/// 1/65535ths).
type Quads = BTreeSet<(u32, u32, Technique, [u32; 2])>;

/// The octahedral impostor draws a renderer recorded on the CPU.
fn cpu_quads(renderer: &Renderer) -> Quads {
    cpu_quads_of(renderer, DrawSource::Octahedral)
}

/// The draws of `source` (octahedral impostors or billboards) a renderer recorded on the CPU.
fn cpu_quads_of(renderer: &Renderer, source: DrawSource) -> Quads {
    renderer
        .draws()
        .iter()
        .filter(|d| d.source == source)
        .map(|d| (d.instance, d.count, d.technique, unorm(d.dither)))
        .collect()
}

/// The octahedral impostor draws the GPU appended in a renderer's last frame (each tree once).
fn gpu_quads(gpu: &Gpu, renderer: &Renderer) -> Quads {
    gpu_quads_of(gpu, renderer, DrawSource::Octahedral)
}

/// The draws of `source` (octahedral impostors, whose quads start at 0, or billboards) the GPU
/// appended in a renderer's last frame (each tree once).
fn gpu_quads_of(gpu: &Gpu, renderer: &Renderer, source: DrawSource) -> Quads {
    let quads = renderer.read_gpu_quads(&gpu.device, &gpu.queue).expect("reads back").expect("the GPU selected");
    let quads: Vec<_> = quads.into_iter().filter(|q| q.source == source).collect();
    assert!(source != DrawSource::Octahedral || quads.iter().all(|q| q.first == 0), "{quads:?}");
    let set: Quads = quads.iter().map(|q| (q.instance, q.count, q.technique, unorm(q.dither))).collect();
    assert_eq!(set.len(), quads.len(), "each tree's quads once");
    set
}

/// With the octahedral impostor among the choices, the hybrid frame draws the impostor's trees
/// on the GPU too: its quad draws are the CPU path's (the same trees, quads, technique and
/// dither), the CPU records none of them, the image is the CPU path's, and the frame's statistics
/// count the quads as the CPU path does (the CPU counts what it hands over).
#[test]
fn octahedral_impostors_are_drawn_on_the_gpu() {
    let gpu = gpu();
    let (container, positions) = octahedral_forest();
    let policy = Policy { transition: 0, occlusion: false, ..Policy::default() };
    let settings = Settings { policy: Some(policy), ..Settings::default() };
    let mut cpu = renderer(&gpu, &container, settings, &positions, false);
    let mut hybrid = renderer(&gpu, &container, settings, &positions, true);
    for (name, camera) in cameras() {
        let (a, cpu_stats) = render_image(&gpu, &mut cpu, &camera, BACKGROUND).expect("renders");
        let (b, stats) = render_image(&gpu, &mut hybrid, &camera, BACKGROUND).expect("renders");
        assert!(stats.gpu_selection, "{name}: {stats:?}");
        assert_eq!(hybrid.instance_techniques(), cpu.instance_techniques(), "{name}: the same assignment");
        let expected = cpu_quads(&cpu);
        eprintln!("{name}: {:?}, {} impostor trees", cpu_stats.instances, expected.len());
        assert!(expected.len() >= 10, "{name}: the far trees are drawn with the impostor: {expected:?}");
        assert_eq!(gpu_quads(&gpu, &hybrid), expected, "{name}: the impostors' draws");
        assert!(cpu_quads(&hybrid).is_empty(), "{name}: the CPU records no impostor");

        let (diff, covered) = differing(&a, &b);
        common::keep(&a, &format!("gpu-octahedral-{name}-cpu"));
        common::keep(&b, &format!("gpu-octahedral-{name}-hybrid"));
        eprintln!("{name}: {diff} of {covered} covered pixels differ");
        assert!(covered > 500, "{name}: the forest is in view");
        assert!(diff * 200 <= covered, "{name}: {diff} of {covered} pixels differ");

        // (The point tree's counts are the GPU's, read back a frame or two later.)
        let octahedral = Technique::Octahedral;
        assert_eq!(stats.instances[octahedral], cpu_stats.instances[octahedral], "{name}: {stats:?}");
        assert_eq!(stats.by_technique[octahedral], cpu_stats.by_technique[octahedral], "{name}: this frame's");
        let quads = |s: &treelod_render::FrameStats| s.submitted[treelod_render::Primitive::Billboard];
        assert_eq!(quads(&stats), quads(&cpu_stats), "{name}: quads submitted");
        assert!(quads(&stats) as usize >= expected.len(), "{name}");
    }
}

/// The camera flies into the impostors' forest with transitions of 4 frames: every octahedral
/// impostor draw of the CPU path is drawn by the hybrid frame with the same technique and share
/// of the dither, by the GPU where the point tree leaves the tree's slot free (a tree fading
/// between the impostor and the LoD chain, say) and by the CPU where it does not (a tree fading
/// between the impostor and the point tree), and the images match.
#[test]
fn impostor_trees_fade_on_the_gpu_as_on_the_cpu() {
    let gpu = gpu();
    let (container, positions) = octahedral_forest();
    let (mut cpu, mut hybrid) = fading_renderers(&gpu, &container, &positions, Policy::DEFAULT_TARGET);
    let (mut fading_on_gpu, mut on_cpu) = (0, 0);
    for frame in 0..16 {
        let (a, b) = flight_frame(&gpu, (&mut cpu, &mut hybrid), frame, 10.0, "");
        let (on_gpu, kept) = (gpu_quads(&gpu, &hybrid), cpu_quads(&hybrid));
        assert_quads_split(&on_gpu, &kept, &cpu_quads(&cpu), (&a, &b), &format!("frame {frame}"));
        fading_on_gpu += on_gpu.iter().filter(|q| q.3 != [0, 65535]).count();
        on_cpu += kept.len();
    }
    eprintln!("{fading_on_gpu} impostor draws fading on the GPU, {on_cpu} left to the CPU");
    assert!(fading_on_gpu > 0, "the flight has impostor trees in a transition");
}

/// With shadows, the camera's view is selected as in a frame without them (the point tree's
/// trees and the impostor trees on the GPU) and the cascades on the CPU as in a CPU frame,
/// streaming what they select: the same cascades' statistics, the same impostor draws, and the
/// same shadowed image, in the forests of the demo tree with and without its impostor (whose
/// cascades draw impostors, and point trees).
#[test]
fn shadow_frames_select_the_camera_s_trees_on_the_gpu() {
    let gpu = gpu();
    let policy = Policy { transition: 0, occlusion: false, ..Policy::default() };
    let shadows =
        Some(treelod_render::Shadows { distance: 400.0, resolution: 1024, ..treelod_render::Shadows::default() });
    let settings = Settings { policy: Some(policy), shadows, ..Settings::default() };
    let (with_impostor, positions) = octahedral_forest();
    let (without, _, _) = demo_forest();
    let mut streamed_point_trees = 0;
    for (forest, container) in [("impostor", with_impostor), ("point tree", without)] {
        let mut cpu = renderer(&gpu, &container, settings, &positions, false);
        let mut hybrid = renderer(&gpu, &container, settings, &positions, true);
        for (name, camera) in cameras() {
            let name = format!("{forest}, {name}");
            let (a, cpu_stats) = render_image(&gpu, &mut cpu, &camera, BACKGROUND).expect("renders");
            let (b, stats) = render_image(&gpu, &mut hybrid, &camera, BACKGROUND).expect("renders");
            assert!(stats.gpu_selection && !cpu_stats.gpu_selection, "{name}: {stats:?}");
            eprintln!("{name}: {:?}", stats.shadow);
            assert!(stats.shadow.cascades > 0 && stats.shadow.submitted.total() > 0, "{name}: shadows are cast");
            assert_eq!(stats.shadow, cpu_stats.shadow, "{name}: the cascades' selection");
            streamed_point_trees += stats.shadow.instances[Technique::Spt];
            assert_eq!(hybrid.instance_techniques(), cpu.instance_techniques(), "{name}");
            assert_eq!(gpu_quads(&gpu, &hybrid), cpu_quads(&cpu), "{name}: the impostors' draws");
            let (diff, covered) = differing(&a, &b);
            common::keep(&a, &format!("gpu-shadows-{forest}-{name}-cpu"));
            common::keep(&b, &format!("gpu-shadows-{forest}-{name}-hybrid"));
            eprintln!("{name}: {diff} of {covered} covered pixels differ");
            assert!(covered > 500, "{name}: the forest is in view");
            assert!(diff * 200 <= covered, "{name}: {diff} of {covered} pixels differ");
        }
    }
    assert!(streamed_point_trees > 0, "some cascade draws point trees, streamed on the CPU");
}

/// More impostor trees than a bucket starts with (2^16 slots) in the first frame: the quad or
/// billboard bucket grows before the frame is selected, so every one is drawn (the point tree's
/// buckets grow from what earlier frames read back; the CPU knows how many impostors it hands
/// over). Trees a few pixels high are drawn with the octahedral impostor or the billboards,
/// whichever the demo tree's tables put first at the smallest heights; the test takes the bucket
/// that holds more of them.
#[test]
fn every_impostor_tree_is_drawn_from_the_first_frame() {
    let gpu = gpu();
    let (container, _) = octahedral_forest();
    let centre = ModelLod::from_container(&container).centre();
    // 100,000 trees 300 to 700 m ahead, 2 m apart: a few pixels each.
    let positions: Vec<Vec3> = (0..100_000)
        .map(|i| vec3((i % 500) as f32 * 2.0 - 500.0, -centre.y, -300.0 - (i / 500) as f32 * 2.0))
        .collect();
    let policy = Policy { transition: 0, occlusion: false, ..Policy::default() };
    let settings = Settings { policy: Some(policy), ..Settings::default() };
    let mut hybrid = renderer(&gpu, &container, settings, &positions, true);
    let camera = Camera::look_at(vec3(0.0, 30.0, 0.0), vec3(0.0, 0.0, -500.0), 1.6, 128, 128);
    let stats = hybrid.prepare(&gpu.device, &gpu.queue, &camera);
    let octahedral = stats.instances[Technique::Octahedral];
    let billboards = stats.instances[Technique::Billboard] + stats.instances[Technique::Crossed];
    let (impostors, source) = if octahedral >= billboards {
        (octahedral, DrawSource::Octahedral)
    } else {
        (billboards, DrawSource::Billboards)
    };
    eprintln!("{impostors} impostor trees ({source:?}) in view of {}: {:?}", positions.len(), stats.instances);
    assert!(impostors > 1 << 16, "more impostor trees than a bucket's first slots: {impostors}");
    let quads = gpu_quads_of(&gpu, &hybrid, source);
    assert_eq!(quads.len(), impostors as usize, "every impostor tree drawn");
}

/// Two models, the first without an octahedral impostor and the second with one, their trees
/// interleaved: each model's impostor trees go to its own quad bucket (none to the first's), and
/// the draws and the image are the CPU path's.
#[test]
fn each_model_s_impostors_go_to_its_own_bucket() {
    let gpu = gpu();
    let (with, positions) = octahedral_forest();
    let (without, _, _) = demo_forest();
    let policy = Policy { transition: 0, occlusion: false, ..Policy::default() };
    let settings = Settings { policy: Some(policy), upload_budget: 1 << 30, ..Settings::default() };
    let make = |on_gpu: bool| {
        let mut renderer = Renderer::new(&gpu.device, Gpu::formats(), settings);
        let first = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&without)).expect("model");
        let second = renderer.add_model(&gpu.device, &gpu.queue, Arc::clone(&with)).expect("model");
        if on_gpu {
            renderer.enable_gpu_selection(&gpu.device, &gpu.queue).expect("fits");
        }
        let instances: Vec<Instance> = (0..)
            .zip(&positions)
            .map(|(i, &p)| Instance {
                model: if i % 2 == 0 { first } else { second },
                transform: Mat4::from_translation(p),
            })
            .collect();
        renderer.set_instances(&instances);
        renderer
    };
    let (mut cpu, mut hybrid) = (make(false), make(true));
    for (name, camera) in cameras() {
        let (a, _) = render_image(&gpu, &mut cpu, &camera, BACKGROUND).expect("renders");
        let (b, stats) = render_image(&gpu, &mut hybrid, &camera, BACKGROUND).expect("renders");
        assert!(stats.gpu_selection, "{name}");
        assert_eq!(hybrid.instance_techniques(), cpu.instance_techniques(), "{name}");
        let quads = hybrid.read_gpu_quads(&gpu.device, &gpu.queue).expect("reads back").expect("the GPU selected");
        let quads: Vec<_> = quads.into_iter().filter(|q| q.source == DrawSource::Octahedral).collect();
        assert!(!quads.is_empty() && quads.iter().all(|q| q.model == 1 && q.instance % 2 == 1), "{name}: {quads:?}");
        assert_eq!(gpu_quads(&gpu, &hybrid), cpu_quads(&cpu), "{name}: the impostors' draws");
        let (diff, covered) = differing(&a, &b);
        eprintln!("{name}: {} impostor trees, {diff} of {covered} covered pixels differ", quads.len());
        assert!(covered > 500 && diff * 200 <= covered, "{name}: {diff} of {covered} pixels differ");
    }
}

/// [`calibrated_demo_without_octahedral`], and the same without its facing billboard (its
/// crossed billboards only), as a container of 1.11 reads (the policy then has the crossed
/// billboards where it had the facing one).
fn billboard_containers() -> [(&'static str, Arc<Container>); 2] {
    let both = calibrated_demo_without_octahedral();
    let mut data = treelod_format::ContainerData::from_container(&both);
    assert!(data.billboards.iter().any(|b| b.kind == treelod_format::billboard_kind::FACING), "a facing billboard");
    data.billboards.retain(|b| b.kind == treelod_format::billboard_kind::CROSSED);
    assert!(!data.billboards.is_empty(), "crossed billboards");
    let bytes = data.to_bytes(treelod_format::Compression::None).expect("encodes");
    let crossed = Arc::new(Container::from_bytes(&bytes).expect("opens"));
    [("facing", both), ("crossed", crossed)]
}

/// The billboard draws the GPU appended in a renderer's last frame (each tree once), each of the
/// model's facing or crossed range (`ranges`: first and count of each).
fn gpu_billboards(gpu: &Gpu, renderer: &Renderer, ranges: &[(u32, u32)]) -> Quads {
    let quads = renderer.read_gpu_quads(&gpu.device, &gpu.queue).expect("reads back").expect("the GPU selected");
    let quads: Vec<_> = quads.into_iter().filter(|q| q.source == DrawSource::Billboards).collect();
    assert!(quads.iter().all(|q| ranges.contains(&(q.first, q.count))), "{quads:?} of {ranges:?}");
    gpu_quads_of(gpu, renderer, DrawSource::Billboards)
}

/// With billboards among the choices (the policy's target raised until they are the cheapest
/// that meet it, and at the default target), the hybrid frame draws the billboard trees on the
/// GPU: its billboard draws are the CPU path's (the same trees, range, technique and dither),
/// the CPU records none of them, the image is the CPU path's, and the statistics count the quads
/// as the CPU path does; then along a flight with transitions of 4 frames, at the least target
/// of a few that draws some of its farthest view's trees with billboards, every billboard draw
/// of the CPU path is drawn by the hybrid frame, by the GPU or (a tree fading between its
/// billboards and the point tree) the CPU, never both.
#[test]
fn billboard_trees_are_drawn_on_the_gpu() {
    let gpu = gpu();
    for (kind, container) in billboard_containers() {
        let (representations, _) = treelod_runtime::Representations::from_container(&container);
        let billboards = representations.billboards.expect("the demo tree has billboards");
        let ranges = [billboards.facing, billboards.crossed];
        let technique = if kind == "facing" { Technique::Billboard } else { Technique::Crossed };
        let positions = positions(&ModelLod::from_container(&container));
        // (At the default target the demo tree's far trees are crossed billboards, or drawn with
        // another technique, in either container, as the build's calibration decides: the
        // second's would repeat the first's.)
        let targets: &[f32] = if kind == "facing" { &[1.0, Policy::DEFAULT_TARGET] } else { &[1.0] };
        for &target in targets {
            let policy = Policy { target, transition: 0, occlusion: false, ..Policy::default() };
            let settings = Settings { policy: Some(policy), ..Settings::default() };
            let mut cpu = renderer(&gpu, &container, settings, &positions, false);
            let mut hybrid = renderer(&gpu, &container, settings, &positions, true);
            for (name, camera) in cameras() {
                let name = format!("{kind}, target {target}, {name}");
                let (a, cpu_stats) = render_image(&gpu, &mut cpu, &camera, BACKGROUND).expect("renders");
                let (b, stats) = render_image(&gpu, &mut hybrid, &camera, BACKGROUND).expect("renders");
                assert!(stats.gpu_selection, "{name}: {stats:?}");
                assert_eq!(hybrid.instance_techniques(), cpu.instance_techniques(), "{name}: the same assignment");
                let expected = cpu_quads_of(&cpu, DrawSource::Billboards);
                eprintln!("{name}: {:?}, {} billboard trees", cpu_stats.instances, expected.len());
                if target == 1.0 {
                    assert!(expected.len() >= 10, "{name}: the trees are drawn with billboards: {expected:?}");
                    assert!(cpu_stats.instances[technique] as usize >= expected.len(), "{name}: {cpu_stats:?}");
                }
                assert_eq!(gpu_billboards(&gpu, &hybrid, &ranges), expected, "{name}: the billboards' draws");
                assert!(cpu_quads_of(&hybrid, DrawSource::Billboards).is_empty(), "{name}: the CPU records none");
                let (diff, covered) = differing(&a, &b);
                common::keep(&a, &format!("gpu-billboards-{kind}-{name}-cpu"));
                common::keep(&b, &format!("gpu-billboards-{kind}-{name}-hybrid"));
                eprintln!("{name}: {diff} of {covered} covered pixels differ");
                assert!(covered > 500, "{name}: the forest is in view");
                assert!(diff * 200 <= covered, "{name}: {diff} of {covered} pixels differ");
                assert_eq!(stats.instances[technique], cpu_stats.instances[technique], "{name}: {stats:?}");
                assert_eq!(stats.by_technique[technique], cpu_stats.by_technique[technique], "{name}: this frame's");
                let quads = |s: &treelod_render::FrameStats| s.submitted[treelod_render::Primitive::Billboard];
                assert_eq!(quads(&stats), quads(&cpu_stats), "{name}: quads submitted");
            }
        }
        if kind != "facing" {
            continue;
        }
        // The flight's target: the least of a few at which the policy draws some trees of its
        // first (farthest) view with billboards, so that they change technique as the camera
        // comes nearer. (Which target that is depends on the build's calibration, not fixed here.)
        let target = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0]
            .into_iter()
            .find(|&target| {
                let policy = Policy { target, transition: 0, occlusion: false, ..Policy::default() };
                let settings = Settings { policy: Some(policy), ..Settings::default() };
                let mut cpu = renderer(&gpu, &container, settings, &positions, false);
                render_image(&gpu, &mut cpu, &flight_camera(0, 10.0), BACKGROUND).expect("renders");
                !cpu_quads_of(&cpu, DrawSource::Billboards).is_empty()
            })
            .expect("at target 1 every tree is drawn with billboards");
        eprintln!("{kind}: the flight's target {target}");
        let (mut cpu, mut hybrid) = fading_renderers(&gpu, &container, &positions, target);
        let (mut drawn_on_gpu, mut fading_on_gpu) = (0, 0);
        for frame in 0..16 {
            let (a, b) = flight_frame(&gpu, (&mut cpu, &mut hybrid), frame, 10.0, &format!("{kind}, "));
            let (on_gpu, kept) =
                (gpu_billboards(&gpu, &hybrid, &ranges), cpu_quads_of(&hybrid, DrawSource::Billboards));
            let expected = cpu_quads_of(&cpu, DrawSource::Billboards);
            assert_quads_split(&on_gpu, &kept, &expected, (&a, &b), &format!("{kind}, frame {frame}"));
            drawn_on_gpu += on_gpu.len();
            fading_on_gpu += on_gpu.iter().filter(|q| q.3 != [0, 65535]).count();
        }
        eprintln!("{kind}: {drawn_on_gpu} billboard draws on the GPU along the flight, {fading_on_gpu} fading");
        assert!(drawn_on_gpu > 0, "{kind}: the flight draws billboard trees on the GPU");
    }
}
