//! Ground truth for penumbra: CPU reference renderer and image metrics.
