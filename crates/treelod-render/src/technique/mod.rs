//! What each representation owns in the renderer: one module per technique (or group of
//! techniques) with the records it uploads (never a file record with a field reused for other
//! data unless the module says so). Their per-frame selection lives in the runtime
//! (`treelod_runtime::{prune, impostor, ellipsoid, baseline}::select`, dispatched per instance by
//! `Renderer::select_view`), their draws are recorded by `crate::draws`, and their WGSL lies in
//! `shaders/tree/<name>.wgsl`. Pruned trees need nothing of their own here: their triangles are in
//! the model's whole-triangle list (`crate::upload`).

pub(crate) mod baselines;
pub(crate) mod ellipsoids;
pub(crate) mod impostors;
