//! penumbra
