//! A window that draws a tree with `treelod_render`: winit 0.30 and wgpu 30, an orbiting camera.
//!
//! ```sh
//! cargo run -p treelod-render --example window                  # the built-in demo tree
//! cargo run -p treelod-render --example window -- tree.treelod  # a container of yours
//! ```
//!
//! Everything treelod needs is in `Gfx::new` (a device with `Renderer::required_features`, a
//! `Renderer` for the surface's formats, `add_model`, `set_instances`) and `Gfx::draw`
//! (`prepare`, then `render` inside the frame's render pass).

use std::error::Error;
use std::sync::Arc;
use std::time::Instant;

use glam::{Mat4, Vec3};
use treelod_format::Container;
use treelod_render::{Camera, Instance, Renderer, RendererFormats, Settings};
use winit::application::ApplicationHandler;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, EventLoop, OwnedDisplayHandle};
use winit::window::{Window, WindowId};

const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const FOVY: f32 = 0.8;

fn main() -> Result<(), Box<dyn Error>> {
    let container = match std::env::args_os().nth(1) {
        Some(path) => Container::open(path)?,
        None => demo_container()?,
    };
    let event_loop = EventLoop::new()?;
    let mut app =
        App { display: event_loop.owned_display_handle(), container: Arc::new(container), gfx: None, error: None };
    event_loop.run_app(&mut app)?;
    app.error.map_or(Ok(()), Err)
}

/// The built-in demo tree, built in memory (`treelod demo -o demo.treelod` writes the same).
fn demo_container() -> Result<Container, Box<dyn Error>> {
    use treelod_build::{BuildConfig, DemoTreeConfig, Placed, build_block, demo_tree};
    let tree = demo_tree(&DemoTreeConfig::default());
    let placed = [Placed { scene: &tree, translation: Vec3::ZERO }];
    let built = build_block("demo", &placed, &BuildConfig::default(), "window example")?;
    Ok(Container::from_bytes(&built.data.to_bytes(treelod_format::Compression::None)?)?)
}

struct App {
    display: OwnedDisplayHandle,
    container: Arc<Container>,
    gfx: Option<Gfx>,
    error: Option<Box<dyn Error>>,
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.gfx.is_none() {
            match Gfx::new(event_loop, self.display.clone(), self.container.clone()) {
                Ok(gfx) => self.gfx = Some(gfx),
                Err(e) => {
                    self.error = Some(e);
                    event_loop.exit();
                }
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        let Some(gfx) = &mut self.gfx else { return };
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => gfx.resize(size.width, size.height),
            WindowEvent::RedrawRequested => gfx.draw(),
            _ => {}
        }
    }
}

/// The window, its surface and device, and the renderer.
struct Gfx {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    config: wgpu::SurfaceConfiguration,
    depth: wgpu::TextureView,
    renderer: Renderer,
    /// Centre and radius of the tree's bounds, for the orbit.
    centre: Vec3,
    radius: f32,
    start: Instant,
}

impl Gfx {
    fn new(
        event_loop: &ActiveEventLoop,
        display: OwnedDisplayHandle,
        container: Arc<Container>,
    ) -> Result<Self, Box<dyn Error>> {
        let window = Arc::new(event_loop.create_window(Window::default_attributes().with_title("treelod"))?);
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_with_display_handle_from_env(Box::new(display)));
        let surface = instance.create_surface(window.clone())?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            compatible_surface: Some(&surface),
            ..Default::default()
        }))?;
        // The renderer needs indirect draws with a first instance.
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            required_features: Renderer::required_features(),
            required_limits: adapter.limits(),
            ..Default::default()
        }))?;

        // An sRGB surface format: the renderer writes linear colours.
        let caps = surface.get_capabilities(&adapter);
        let format = caps.formats.iter().copied().find(|f| f.is_srgb()).or(caps.formats.first().copied());
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&adapter, size.width.max(1), size.height.max(1))
            .ok_or("the adapter cannot present to this window")?;
        config.format = format.ok_or("the surface offers no format")?;
        surface.configure(&device, &config);
        let depth = depth_view(&device, &config);

        let formats = RendererFormats { color: config.format, depth: DEPTH_FORMAT, sample_count: 1 };
        let mut renderer = Renderer::new(&device, formats, Settings::default());
        let block = container.block();
        let (lo, hi) = (Vec3::from_array(block.bounds_min), Vec3::from_array(block.bounds_max));
        let tree = renderer.add_model(&device, &queue, container)?;
        renderer.set_instances(&[Instance { model: tree, transform: Mat4::IDENTITY }]);

        let (centre, radius) = (0.5 * (lo + hi), (0.5 * (hi - lo).length()).max(0.1));
        window.request_redraw();
        Ok(Self { window, surface, device, queue, config, depth, renderer, centre, radius, start: Instant::now() })
    }

    fn resize(&mut self, width: u32, height: u32) {
        if width > 0 && height > 0 {
            (self.config.width, self.config.height) = (width, height);
            self.surface.configure(&self.device, &self.config);
            self.depth = depth_view(&self.device, &self.config);
        }
    }

    fn draw(&mut self) {
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(frame) | wgpu::CurrentSurfaceTexture::Suboptimal(frame) => frame,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&self.device, &self.config);
                self.window.request_redraw();
                return;
            }
            // Timeout, occluded: try again with the next redraw.
            _ => return,
        };

        // Once round the tree every 20 s, from a little above.
        let angle = self.start.elapsed().as_secs_f32() * std::f32::consts::TAU / 20.0;
        let distance = 1.1 * self.radius / (0.5 * FOVY).sin();
        let eye = self.centre + distance * Vec3::new(angle.sin(), 0.3, angle.cos()).normalize();
        let camera = Camera::look_at(eye, self.centre, FOVY, self.config.width, self.config.height);
        self.renderer.prepare(&self.device, &self.queue, &camera);

        let view = frame.texture.create_view(&wgpu::TextureViewDescriptor::default());
        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::WHITE),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.depth,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Store }),
                    stencil_ops: None,
                }),
                ..Default::default()
            });
            self.renderer.render(&mut pass);
        }
        self.queue.submit([encoder.finish()]);
        self.window.pre_present_notify();
        self.queue.present(frame);
        self.window.request_redraw();
    }
}

fn depth_view(device: &wgpu::Device, config: &wgpu::SurfaceConfiguration) -> wgpu::TextureView {
    device
        .create_texture(&wgpu::TextureDescriptor {
            label: Some("depth"),
            size: wgpu::Extent3d { width: config.width, height: config.height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        })
        .create_view(&wgpu::TextureViewDescriptor::default())
}
