//! Seamless tiles and tile sets (ARCHITECTURE §7).
//!
//! Somol–Haindl: minimum-error stitching with adaptive blending ([`stitch`],
//! §2.1–2.2), the template tile ([`template`], §3.1), patch insertion
//! ([`patch`], §2.3), derived tile sets ([`tileset`], §3.2) and index-matrix
//! tiling ([`grid`]). ω-tiles of Dong, Zhou and Paul: the sets ([`omega`],
//! §3), the immune search ([`ais`], [`evaluate`], §4) and the tiles
//! ([`build`], [`graphcut`], §4.3). [`config`] holds both methods' validated
//! settings, [`make`] writes a set into a directory and [`file`] is its
//! `tileset.json`, written and read by one type.

pub mod ais;
pub mod build;
pub mod config;
pub mod evaluate;
pub mod file;
pub mod graphcut;
pub mod grid;
pub mod make;
pub mod omega;
pub mod patch;
pub mod stitch;
pub mod template;
pub mod tileset;

pub use config::{MakeConfig, OmegaConfig, SomolConfig};
pub use file::{load_tiles, tile_paths, TileSetFile};
pub use grid::{assemble, check_grid, check_index, layout, random_index, read_index, Layout};
pub use make::{make_omega, make_somol, omega_evaluator, Made};
pub use patch::{insert_patch, PatchReport};
pub use stitch::Blend;
pub use template::{choose_template, make_template, Rect, TemplateChoice};
pub use tileset::{make_tile_set, DerivedTile, PathSearch, TileSet, TileSetSettings, Wrap};
