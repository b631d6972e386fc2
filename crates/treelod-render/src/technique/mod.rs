//! What each representation owns in the renderer: one module per technique (or group of
//! techniques) with its per-frame selection into a view's draw lists (`impl Renderer` blocks
//! called by `Renderer::select_view`), its GPU-side model data and the records it uploads. Its
//! WGSL lies in `shaders/tree/<name>.wgsl`; the sequential point tree and the full mesh are
//! selected by `treelod_runtime::select_frame` in the core.

pub(crate) mod baselines;
pub(crate) mod ellipsoids;
pub(crate) mod impostors;
pub(crate) mod pruned;
