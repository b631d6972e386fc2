//! Impostor planes lit as their leaves take the sun (spec §6.10.2, `PLANE_DIFFUSE`) on the Vulkan
//! backend (Mesa lavapipe in CI): the sun's diffuse factor of a plane is `√(a·c² + b·(1 − c²))`,
//! `c` the cosine of the sun to its normal, from the records the build writes; without them a
//! plane is lit by its own normal, as before 1.10.

mod common;

use std::sync::Arc;

use common::{BACKGROUND, covered, demo_built, gpu, keep, one_tree};
use glam::{Vec3, vec3};
use treelod_build::{BuildConfig, ImpostorConfig};
use treelod_format::{Compression, Container, ContainerData, PlaneDiffuseRecord};
use treelod_render::offscreen::{Gpu, Image, render_image};
use treelod_render::{Camera, DebugView, Settings, Technique};

/// The demo tree with impostors, as written.
fn demo() -> ContainerData {
    let built = demo_built(&BuildConfig { impostors: Some(ImpostorConfig::default()), ..BuildConfig::default() });
    ContainerData::from_container(&built)
}

/// `data` with every plane's record `record` (`None`: without the section).
fn with_records(data: &ContainerData, record: Option<PlaneDiffuseRecord>) -> Arc<Container> {
    let plane_diffuse = record.map_or_else(Vec::new, |r| vec![r; data.planes.len()]);
    let data = ContainerData { plane_diffuse, ..data.clone() };
    Arc::new(Container::from_bytes(&data.to_bytes(Compression::None).expect("encodes")).expect("opens"))
}

/// The demo tree's impostors from two sides, 160 × 160, lit with `settings`, from `distance`
/// metres with a field of view that frames the tree.
fn render(gpu: &Gpu, container: &Arc<Container>, settings: Settings, distance: f32) -> Vec<Image> {
    let block = container.block();
    let centre = 0.5 * (Vec3::from_array(block.bounds_min) + Vec3::from_array(block.bounds_max));
    let mut renderer = one_tree(gpu, container, Settings { technique: Technique::Impostors, ..settings });
    directions()
        .iter()
        .map(|&d| {
            let camera = Camera::look_at(centre + distance * d, centre, 0.8 * 18.0 / distance, 160, 160);
            render_image(gpu, &mut renderer, &camera, BACKGROUND).expect("renders").0
        })
        .collect()
}

/// The directions the views look from, towards the viewer.
fn directions() -> [Vec3; 2] {
    [0.3f32, 2.4].map(|a| vec3(a.sin(), 0.3, a.cos()).normalize())
}

/// sRGB byte to linear.
fn linear(v: u8) -> f64 {
    let c = f64::from(v) / 255.0;
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

#[test]
fn a_plane_takes_the_sun_as_its_records_say() {
    let gpu = gpu();
    let data = demo();
    assert_eq!(data.plane_diffuse.len(), data.planes.len(), "the build writes one record per plane");
    assert!(
        data.plane_diffuse.iter().any(|r| *r != PlaneDiffuseRecord::FLAT),
        "the demo's leaves are not all in their planes: {:?}",
        &data.plane_diffuse[..4]
    );
    let settings = Settings { shadows: None, ..Settings::default() };

    // Without the section, planes are lit by their own normals: as with flat records.
    let absent = render(&gpu, &with_records(&data, None), settings, 18.0);
    let flat = render(&gpu, &with_records(&data, Some(PlaneDiffuseRecord::FLAT)), settings, 18.0);
    assert_eq!(absent, flat, "no records reads as leaves in the plane");
    let as_built = Arc::new(Container::from_bytes(&data.to_bytes(Compression::None).expect("encodes")).expect("opens"));
    assert_ne!(render(&gpu, &as_built, settings, 18.0), flat, "the build's records change the light");

    // Leaves turned every way, lit from behind the viewer (the sun along the view, the camera
    // far and narrow so every pixel looks the same way): `|v·l| = 1`, so they take
    // (2/3π)·(π/2) / (1/2) = 2/3 of the sun, whatever each plane's normal. The sun alone
    // (no ambient) against the albedo alone (ambient only, no occlusion):
    let scattered = with_records(&data, Some(PlaneDiffuseRecord { flat: 0, scattered: u16::MAX }));
    for (k, d) in directions().into_iter().enumerate() {
        let lit = |ambient: f32| {
            let settings = Settings { sun: d, ambient, ambient_occlusion: false, ..settings };
            render(&gpu, &scattered, settings, 180.0).swap_remove(k)
        };
        let (sun, albedo) = (lit(0.0), lit(1.0));
        keep(&sun, &format!("plane_diffuse_sun_{k}"));
        assert_eq!(covered(&sun), covered(&albedo), "the light changes no coverage");
        // The planes' pixels (the kinds view paints them yellow; the bark is lit by its normals).
        let kinds = render(&gpu, &scattered, Settings { debug: DebugView::Kinds, ..settings }, 180.0).swap_remove(k);
        let mut ratios = Vec::new();
        for ((s, a), kind) in sun.rgba.chunks_exact(4).zip(albedo.rgba.chunks_exact(4)).zip(kinds.rgba.chunks_exact(4))
        {
            let plane = kind[0] > 200 && kind[1] > 150 && kind[2] < 150;
            // Channels bright enough that 8 bits resolve the ratio to a few per cent.
            for c in 0..3 {
                if plane && a[c] >= 96 {
                    ratios.push(linear(s[c]) / linear(a[c]));
                }
            }
        }
        assert!(ratios.len() > 100, "view {k}: {} bright channels", ratios.len());
        let (lo, hi) = ratios.iter().fold((f64::MAX, f64::MIN), |(lo, hi), &r| (lo.min(r), hi.max(r)));
        assert!(lo > 0.64 && hi < 0.69, "view {k}: the sun's share {lo:.3} .. {hi:.3}, not 2/3");
    }
}
