//! Tests of the solid synthesis: eq. 4 in each view's plane, weight
//! volumes, the memory check.

use super::lattice::{initial, upsample};
use super::weights::{downsample3, ramp};
use super::*;

fn plain(w: usize, h: usize) -> ColorImage {
    ColorImage::from_vec(w, h, vec![0; w * h * 3])
}

#[test]
fn initial_and_upsampled_coordinates_follow_eq_4_in_each_view_s_plane() {
    let e = plain(16, 16);
    let views: Vec<View> = Axis::ALL
        .into_iter()
        .map(|axis| View {
            axis,
            exemplar: &e,
            material: 0,
        })
        .collect();
    let (ps, ls) = ([3, 2, 4], [6, 4, 8]);
    let coarse = initial(ps, &views, 4);
    let fine = upsample(&coarse, ps, ls, &views, 2);
    let at = |c: &[[u32; 2]], s: [usize; 3], p: [usize; 3], j: usize| {
        c[((p[2] * s[1] + p[1]) * s[0] + p[0]) * 3 + j]
    };
    for z in 0..ls[2] {
        for y in 0..ls[1] {
            for x in 0..ls[0] {
                let q = [x, y, z];
                let p = [x / 2, y / 2, z / 2];
                for (j, v) in views.iter().enumerate() {
                    let [u, w] = v.axis.plane();
                    // §5.1: the coarse level is P_{u,v}·h mod s_e.
                    assert_eq!(
                        at(&coarse, ps, p, j),
                        [(p[u] * 4 % 16) as u32, (p[w] * 4 % 16) as u32]
                    );
                    // Eq. 4 in pyramid units (stack coordinates / h):
                    // 2·S(P) + Δ_{u,v}, the same for both children
                    // across the view's own axis.
                    let s = at(&coarse, ps, p, j).map(|c| c / 4);
                    let want = [
                        (2 * s[0] + (q[u] % 2) as u32) % 8,
                        (2 * s[1] + (q[w] % 2) as u32) % 8,
                    ];
                    assert_eq!(at(&fine, ls, q, j).map(|c| c / 2), want);
                }
            }
        }
    }
}

#[test]
fn weight_volumes_downsample_to_block_means_that_still_sum_to_one() {
    let size = [7, 5, 6];
    let maps = ramp(3, Axis::Y, size);
    for h in [1, 2, 4] {
        let down: Vec<Vec<f32>> = maps.iter().map(|w| downsample3(w, size, h)).collect();
        let n = size.map(|s| s.div_ceil(h)).iter().product::<usize>();
        for i in 0..n {
            let sum: f32 = down.iter().map(|w| w[i]).sum();
            assert!((sum - 1.0).abs() < 1e-5, "h {h} voxel {i}: {sum}");
        }
    }
    // A block mean, by hand: h = 2, voxel (1, 1, 0) covers x 2..4,
    // y 2..4, z 0..2.
    let d = downsample3(&maps[0], size, 2);
    let mut sum = 0.0;
    for z in 0..2 {
        for y in 2..4 {
            for x in 2..4 {
                sum += maps[0][(z * 5 + y) * 7 + x];
            }
        }
    }
    assert!((d[4 + 1] - sum / 8.0).abs() < 1e-6);
}

#[test]
fn memory_grows_with_the_voxels_and_a_solid_too_large_is_refused_first() {
    let a = memory_needed([64; 3], 3, 1, 8);
    assert_eq!(memory_needed([128; 3], 3, 1, 8), 8 * a);
    let e = plain(16, 16);
    let views = [View {
        axis: Axis::Z,
        exemplar: &e,
        material: 0,
    }];
    let mut settings = SolidSettings::default();
    settings.base.budget = crate::budget::Budget { cap: Some(1 << 20) };
    let mut b = crate::search::LocalSearch::new(texsyn_engine::Engine::default());
    let err = synthesize(
        &views,
        &MaterialWeights::Single,
        [64; 3],
        &settings,
        &mut b,
        &crate::progress::Silent,
    )
    .err()
    .unwrap();
    assert!(format!("{err}").contains("of memory"), "{err}");
}
