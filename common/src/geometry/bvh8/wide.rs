//! Two packets through one walk, sixteen lanes an instruction, on hosts with AVX-512.
//!
//! The binaries are built for `x86-64-v3` (AVX2), so an AVX-512 host runs the eight-lane walk
//! of [`Bvh8::intersect_packet`](super::Bvh8::intersect_packet) unless a caller hands it two
//! packets at once ([`Bvh8::intersect_packet_pair`](super::Bvh8::intersect_packet_pair)):
//! then, when the processor has AVX-512 (checked once, at run time), both go through
//! [`walk16`], which is the eight-lane walk with every box and triangle test made for sixteen
//! lanes. Each lane still makes its own query's tests in the same operations (fused
//! multiply-subtract, min, max, division, comparison, each rounded once per lane as in eight
//! lanes), so each lane's hit is the one its single-ray query finds, bit for bit, on any host;
//! only the walk's order and the slots it may skip differ, and neither changes a result (the
//! closest hit wins, ties go to the lowest id). The tree comes as its parts (nodes, triangle
//! packets, the root's box), so this module imports only the layouts of [`super::kernels`].
//!
//! `TESSERA_SIMD=avx2` in the environment keeps the eight-lane walks on an AVX-512 host (to
//! time one against the other in one build); the parent module reads it.

use std::mem::MaybeUninit;

use super::kernels::{
    COUNT_SHIFT, FIRST_MASK, Intervals, LEAF, Node, Packet8, SLACK, Tri4, filled_slots, hmax8, hmin8,
    insert_by_entry,
};

/// Whether the processor runs the sixteen-lane walk (whatever the environment says: the choice
/// is [`super::pair_walks_at_once`]'s).
pub(super) fn detected() -> bool {
    std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512dq")
}

/// The closest hits of the active lanes of `p` (lanes 0-7) and `q` (lanes 8-15) in one walk of
/// the tree of `nodes` (root first), `tris` and the root's box `bounds` (minima, then maxima):
/// what [`Bvh8::intersect_packet`](super::Bvh8::intersect_packet) of each finds, `tmax` and `id` by lane (lane `8 + k` is lane
/// `k` of `q`). Returns the mask of lanes that hit (sixteen bits).
///
/// # Safety
/// The processor has AVX-512 F and DQ ([`detected`]); `stack` holds at least `depth * 7 + 1`
/// entries for the tree's depth.
#[target_feature(enable = "avx512f,avx512dq,avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn walk16<const ONE_NODE: bool>(
    nodes: &[Node],
    tris: &[Tri4],
    bounds: &[f32; 6],
    p: &Packet8,
    q: &Packet8,
    tmax_out: &mut [f32; 16],
    id_out: &mut [u32; 16],
    stack: &mut [MaybeUninit<(u32, u32, f32)>],
) -> u32 {
    use std::arch::x86_64::*;
    // SAFETY: the caller checked AVX-512 F and DQ; every load reads a whole `[f32; 8]`,
    // `[f32; 16]` or `[u32; 16]` (unaligned), and `Node` is 32-byte aligned with 32-byte planes.
    unsafe {
        let ld = |a: &[f32; 8], b: &[f32; 8]| {
            _mm512_insertf32x8::<1>(
                _mm512_castps256_ps512(_mm256_loadu_ps(a.as_ptr())),
                _mm256_loadu_ps(b.as_ptr()),
            )
        };
        let (ox, oy, oz) = (ld(&p.o[0], &q.o[0]), ld(&p.o[1], &q.o[1]), ld(&p.o[2], &q.o[2]));
        let (dx, dy, dz) = (ld(&p.d[0], &q.d[0]), ld(&p.d[1], &q.d[1]), ld(&p.d[2], &q.d[2]));
        let (ix, iy, iz) = (ld(&p.inv[0], &q.inv[0]), ld(&p.inv[1], &q.inv[1]), ld(&p.inv[2], &q.inv[2]));
        let (oix, oiy, oiz) = (
            ld(&p.o_inv_near[0], &q.o_inv_near[0]),
            ld(&p.o_inv_near[1], &q.o_inv_near[1]),
            ld(&p.o_inv_near[2], &q.o_inv_near[2]),
        );
        let (ofx, ofy, ofz) = (
            ld(&p.o_inv_far[0], &q.o_inv_far[0]),
            ld(&p.o_inv_far[1], &q.o_inv_far[1]),
            ld(&p.o_inv_far[2], &q.o_inv_far[2]),
        );
        let tmin = ld(&p.tmin, &q.tmin);
        let active = p.active | q.active << 8;
        let mut tmax = _mm512_loadu_ps(tmax_out.as_ptr());
        let mut ids = _mm512_loadu_si512(id_out.as_ptr().cast());
        let mut hit_lanes = 0u32;
        let grow = _mm512_set1_ps(SLACK);
        let inf = _mm512_set1_ps(f32::INFINITY);
        // The eight-lane walk's box test (`Bvh8::closest_packet`), sixteen lanes at a time.
        let (gx, gy, gz) = (_mm512_sub_ps(oix, ofx), _mm512_sub_ps(oiy, ofy), _mm512_sub_ps(oiz, ofz));
        let enter = |b: [__m512; 6], tmax: __m512| {
            let t0x = _mm512_fmsub_ps(b[0], ix, oix);
            let t1x = _mm512_fmsub_ps(b[3], ix, oix);
            let t0y = _mm512_fmsub_ps(b[1], iy, oiy);
            let t1y = _mm512_fmsub_ps(b[4], iy, oiy);
            let t0z = _mm512_fmsub_ps(b[2], iz, oiz);
            let t1z = _mm512_fmsub_ps(b[5], iz, oiz);
            let tn = _mm512_max_ps(
                _mm512_max_ps(_mm512_min_ps(t0x, t1x), _mm512_min_ps(t0y, t1y)),
                _mm512_max_ps(_mm512_min_ps(t0z, t1z), tmin),
            );
            let tf = _mm512_min_ps(
                _mm512_min_ps(
                    _mm512_add_ps(_mm512_max_ps(t0x, t1x), gx),
                    _mm512_add_ps(_mm512_max_ps(t0y, t1y), gy),
                ),
                _mm512_min_ps(_mm512_add_ps(_mm512_max_ps(t0z, t1z), gz), tmax),
            );
            (tn, u32::from(_mm512_cmp_ps_mask::<_CMP_LE_OQ>(tn, _mm512_mul_ps(tf, grow))))
        };
        let (_, in_root) = enter(std::array::from_fn(|k| _mm512_set1_ps(bounds[k])), tmax);
        let root = in_root & active;
        if root == 0 {
            return 0;
        }
        // The least (greatest) of the sixteen lanes that `keep` marks, the others taken as +inf
        // (-inf), in every lane of an eight-lane register: the halves folded, then the
        // eight-lane walk's reduction.
        let hmin = |v: __m512, keep: u32| {
            let v = _mm512_mask_blend_ps(keep as u16, inf, v);
            hmin8(_mm256_min_ps(_mm512_castps512_ps256(v), _mm512_extractf32x8_ps::<1>(v)))
        };
        let neg_inf = _mm512_set1_ps(f32::NEG_INFINITY);
        let hmax = |v: __m512, keep: u32| {
            let v = _mm512_mask_blend_ps(keep as u16, neg_inf, v);
            hmax8(_mm256_max_ps(_mm512_castps512_ps256(v), _mm512_extractf32x8_ps::<1>(v)))
        };
        // The packet as intervals, and the slots some lane may enter: as in the eight-lane
        // walk (whose comments give the reasoning), over sixteen lanes. A NaN in any lane keeps
        // every filled slot for the exact tests.
        let sum = _mm512_add_ps(_mm512_add_ps(_mm512_add_ps(oix, oiy), oiz), tmax);
        let nan_lanes = u32::from(_mm512_cmp_ps_mask::<_CMP_UNORD_Q>(sum, sum)) & active;
        let keep_all = if nan_lanes == 0 { 0 } else { 0xff };
        let intervals = Intervals {
            inv_lo: [hmin(ix, active), hmin(iy, active), hmin(iz, active)],
            inv_hi: [hmax(ix, active), hmax(iy, active), hmax(iz, active)],
            oinv_lo: [hmin(ofx, active), hmin(ofy, active), hmin(ofz, active)],
            oinv_hi: [hmax(oix, active), hmax(oiy, active), hmax(oiz, active)],
        };
        let tmin8 = hmin(tmin, active);
        let mut sp = 0usize;
        let mut cur = (0u32, root);
        loop {
            let (node_ref, mask) = cur;
            if node_ref & LEAF == 0 {
                let node = &nodes[node_ref as usize];
                let filled = filled_slots(node);
                let mut kids = [(0u32, 0u32, 0f32); 8];
                let mut n = 0;
                let mut slots = if ONE_NODE {
                    filled
                } else {
                    filled & (intervals.slots(node, tmin8, hmax(tmax, active)) | keep_all)
                };
                while slots != 0 {
                    let i = slots.trailing_zeros() as usize;
                    slots &= slots - 1;
                    let (tn, in_box) = enter(std::array::from_fn(|k| _mm512_set1_ps(node.b[k][i])), tmax);
                    let lanes = in_box & mask;
                    if lanes != 0 {
                        // The nearest entry among the lanes that enter orders the children.
                        let entry = _mm256_cvtss_f32(hmin(tn, in_box));
                        insert_by_entry(&mut kids, n, (node.child[i], lanes, entry));
                        n += 1;
                    }
                }
                if n > 0 {
                    for k in &kids[..n - 1] {
                        stack[sp] = MaybeUninit::new(*k);
                        sp += 1;
                    }
                    cur = (kids[n - 1].0, kids[n - 1].1);
                    continue;
                }
            } else {
                let first = (node_ref & FIRST_MASK) as usize;
                let count = ((node_ref & !LEAF) >> COUNT_SHIFT) as usize;
                let zero = _mm512_setzero_ps();
                let signbit = _mm512_set1_ps(-0.0);
                for tri in &tris[first..first + count] {
                    for l in 0..4 {
                        if tri.id[l] == u32::MAX {
                            break;
                        }
                        let c = |v: &[[f32; 4]; 3]| -> [__m512; 3] {
                            std::array::from_fn(|a| _mm512_set1_ps(v[a][l]))
                        };
                        let ([e1x, e1y, e1z], [e2x, e2y, e2z], v0) = (c(&tri.e1), c(&tri.e2), c(&tri.v0));
                        let (sx, sy, sz) =
                            (_mm512_sub_ps(ox, v0[0]), _mm512_sub_ps(oy, v0[1]), _mm512_sub_ps(oz, v0[2]));
                        // `kernels::mt8`'s operations, one triangle against sixteen rays.
                        let px = _mm512_fmsub_ps(dy, e2z, _mm512_mul_ps(dz, e2y));
                        let py = _mm512_fmsub_ps(dz, e2x, _mm512_mul_ps(dx, e2z));
                        let pz = _mm512_fmsub_ps(dx, e2y, _mm512_mul_ps(dy, e2x));
                        let qx = _mm512_fmsub_ps(sy, e1z, _mm512_mul_ps(sz, e1y));
                        let qy = _mm512_fmsub_ps(sz, e1x, _mm512_mul_ps(sx, e1z));
                        let qz = _mm512_fmsub_ps(sx, e1y, _mm512_mul_ps(sy, e1x));
                        let dot = |ax, ay, az, bx, by, bz| {
                            _mm512_fmadd_ps(ax, bx, _mm512_fmadd_ps(ay, by, _mm512_mul_ps(az, bz)))
                        };
                        let det = dot(e1x, e1y, e1z, px, py, pz);
                        let sign = _mm512_and_ps(det, signbit);
                        let adet = _mm512_andnot_ps(signbit, det);
                        let u = _mm512_xor_ps(dot(sx, sy, sz, px, py, pz), sign);
                        let v = _mm512_xor_ps(dot(dx, dy, dz, qx, qy, qz), sign);
                        let tt = _mm512_xor_ps(dot(e2x, e2y, e2z, qx, qy, qz), sign);
                        let ok = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(mask as u16, adet, zero)
                            & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(u, zero)
                            & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(v, zero)
                            & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(_mm512_add_ps(u, v), adet)
                            & _mm512_cmp_ps_mask::<_CMP_GT_OQ>(tt, _mm512_mul_ps(tmin, adet));
                        // `kernels::below`: the far bound, scaled, with slack.
                        let bound = _mm512_mul_ps(_mm512_mul_ps(tmax, adet), grow);
                        let ok = ok & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(tt, bound);
                        if ok == 0 {
                            continue;
                        }
                        // The divided distance decides, ties to the lower id (as signed
                        // integers: "none", u32::MAX, is -1 and loses every tie).
                        let t = _mm512_div_ps(tt, adet);
                        let id = _mm512_set1_epi32(tri.id[l] as i32);
                        let tie =
                            _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(t, tmax) & _mm512_cmpgt_epi32_mask(ids, id);
                        let closer = ok & (_mm512_cmp_ps_mask::<_CMP_LT_OQ>(t, tmax) | tie);
                        tmax = _mm512_mask_blend_ps(closer, tmax, t);
                        ids = _mm512_mask_blend_epi32(closer, ids, id);
                        hit_lanes |= u32::from(closer);
                    }
                }
            }
            // Pop the next node some lane may still reach before its closest hit (with the box
            // test's slack, as in the eight-lane walk).
            loop {
                if sp == 0 {
                    _mm512_storeu_ps(tmax_out.as_mut_ptr(), tmax);
                    _mm512_storeu_si512(id_out.as_mut_ptr().cast(), ids);
                    return hit_lanes;
                }
                sp -= 1;
                // SAFETY: entries below `sp` were written by the pushes above.
                let (c, m, d) = stack[sp].assume_init();
                let bound = _mm512_mul_ps(tmax, grow);
                let reach = u32::from(_mm512_cmp_ps_mask::<_CMP_LE_OQ>(_mm512_set1_ps(d), bound));
                if m & reach != 0 {
                    cur = (c, m & reach);
                    break;
                }
            }
        }
    }
}
