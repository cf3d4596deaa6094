//! Seamless tiles and tile sets after Somol and Haindl (ARCHITECTURE §7):
//! minimum-error paths across overlaps ([`path`], §2.1), stitching with
//! adaptive blending ([`stitch`], §2.2), and patch insertion, template tiles,
//! derived tile sets and index-matrix tiling ([`tileset`], §2.3, §3).

pub mod ais;
pub mod graphcut;
pub mod omega;
pub mod stitch;
pub mod tileset;

pub use tileset::{
    assemble, choose_template, insert_patch, make_template, make_tile_set, random_index,
    PathSearch, Rect, TileSet, TileSetSettings,
};
