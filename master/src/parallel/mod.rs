//! Parallel pixel synthesis on exemplar coordinates (Lefebvre and Hoppe, as
//! Manke and Wünsche §3–4 summarise and extend it to morphing; ARCHITECTURE
//! §10): every level stores exemplar coordinates, so each pixel of a
//! correction sub-pass is computed on its own.
//!
//! - [`driver`]: the one level loop over a [`driver::Lattice`] (a plane or
//!   a volume), the settings and the colour blend `Σ Wʲ·Eʲ(Sʲ)`;
//! - [`neighbourhood`]: the neighbourhoods compared;
//! - [`exemplar`]: an exemplar's level, its bases and the choice of eq. 3;
//! - [`coords`]: coordinate levels, upsampling and the §4.2 jitter;
//! - [`appearance`]: the appearance space (5×5 windows, PCA);
//! - [`candidates`]: k-coherence sets from the engine's top-k search;
//! - [`cache`]: those sets kept on disk, so an exemplar is analysed once;
//! - [`histogram`]: histogram matching of the blend (Kopf et al.), so
//!   corrections keep the exemplar's contrast and thin features;
//! - [`weights`]: weight maps of a morph;
//! - [`synth`]: the plane: synthesis and morph (§3–4);
//! - [`solid`]: the volume: solid textures from 2-D views (§5).

pub mod appearance;
pub mod cache;
pub mod candidates;
pub mod coords;
pub mod driver;
pub mod exemplar;
pub mod histogram;
pub mod neighbourhood;
pub mod solid;
pub mod synth;
pub mod weights;

#[cfg(test)]
pub(crate) mod tests {
    use crate::imaging::ColorImage;

    /// A bundled texture (`assets/textures`) as 8-bit RGB.
    pub fn texture(name: &str) -> ColorImage {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../assets/textures")
            .join(name);
        crate::imaging::load_color(&p).unwrap()
    }
}
