//! Stage 2 (section III): per-triangle correspondence (output triple lists).
//!
//! 1. Per triangle (in parallel), the three vertices' visibility is synthesized at the centre
//!    (eq. 3, clamped to the hemisphere of the averaged normal); the sites go into a spherical
//!    Delaunay triangulation ([`super::hull`]); every hull face whose three sites have three
//!    different vertices ("colours") is an RGB tripoint and gives a candidate triple, sorted by
//!    the tripoint distance `D_RGB` (eq. 22). Candidates with a pair of sites more than
//!    `max_link_deg` apart are dropped (they link unrelated parts of the visibility).
//! 2. Selection: a random triangle (seeded) nominates its best remaining candidate; it is
//!    rejected when it goes through an entity already in the triangle's list (Rule 1) or
//!    crosses a triple already there (Rule 2, the cross-link test of Algorithm 1, cyclic
//!    order of every pair of sequences); its partial triples (the two entities of a shared
//!    edge) go to the edge-adjacent triangles under the same rules, all or nothing.
//! 3. Propagation: every partial triple is completed with the entity of the third vertex that
//!    keeps the order consistent (between its immediate neighbours) and is nearest (eq. 22);
//!    a completed partial sends new partial triples across its two other edges.
//! 4. Relaxed constraints: remaining partial triples are completed and every entity not yet
//!    in a triple gets one, ignoring Rule 1 and without propagation. When a vertex has no
//!    entity within `max_link_deg` (it sees fewer sequences), a virtual point is used (see
//!    [`super`]).
//! 5. The triples of a triangle are grouped by the sequences they link and ordered along them:
//!    each group is one closed loop of the output.
//! 6. Jumps through the pole (ours, issue 9): a vertex's sequence is often split between
//!    groups (arcs, interleaved after the relaxed stage). Closing each arc by a chord is wrong
//!    on the horizon, where a chord between two horizon points runs along the horizon the
//!    shorter way: a group holding two arcs of a horizon ring wound once around the normal, so
//!    eq. 21 at that vertex counted the hemisphere once per group (errors up to 13 sr on the
//!    bunny). Every step of a slot that is not an edge of its vertex's sequence is routed
//!    through that vertex's pole (a virtual direction point, its normal), and every edge is
//!    owned by exactly one loop, so at each vertex the loops are the fan decomposition of its
//!    own loops (`route_jumps`).

use super::hull;
use super::*;
use rayon::prelude::*;
use std::collections::{HashMap, VecDeque};

const NONE: u32 = u32::MAX;
const VIRTUAL_KEY: u32 = 0x8000_0000;
const MAX_COMBOS: usize = 8;
/// Provisional ids of the virtual points a triangle adds in step 4 (renumbered after it).
const TMP_VIRTUAL: u32 = 0x4000_0000;

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Voronoi,
    Partial,
    Propagated,
    Relaxed,
}

#[derive(Clone)]
struct Link {
    e: [u32; 3],
    kind: Kind,
}

#[derive(Default, Clone)]
struct TriState {
    links: Vec<Link>,
    used: [Vec<u32>; 3],
}

struct Ctx {
    vis: VectorizedVisibility,
    /// per vertex point: (sequence, position in it)
    info: Vec<(u32, u32)>,
    /// per triangle: canonical vertex of each slot
    canon: Vec<[u32; 3]>,
    adj: HashMap<(u32, u32), Vec<u32>>,
    centre: Vec<(Vec3, Vec3)>,
    cos_link: f32,
}

impl Ctx {
    fn seq_len(&self, s: u32) -> u32 {
        self.vis.seq_offsets[s as usize + 1] - self.vis.seq_offsets[s as usize]
    }

    fn is_real(&self, g: u32) -> bool {
        g != NONE && g < self.vis.vertex_points
    }

    fn entities(&self, t: usize, k: usize) -> std::ops::Range<u32> {
        let [f, c] = self.vis.vertex_seqs[self.canon[t][k] as usize];
        self.vis.seq_offsets[f as usize]..self.vis.seq_offsets[(f + c) as usize]
    }

    fn dir(&self, t: usize, points: &[[f32; 4]], g: u32) -> Vec3 {
        let (c, n) = self.centre[t];
        clamp_to_hemisphere(synth_dir(points[g as usize], c).unwrap_or(n), n)
    }

    /// Triangles across the edge of slots `(a, b)` of `t`, with the slots of those two vertices.
    fn across(&self, t: usize, a: usize, b: usize) -> Vec<(usize, usize, usize)> {
        let (va, vb) = (self.canon[t][a], self.canon[t][b]);
        let mut out = Vec::new();
        if let Some(list) = self.adj.get(&(va.min(vb), va.max(vb))) {
            for &u in list {
                let u = u as usize;
                if u == t {
                    continue;
                }
                let sa = self.canon[u].iter().position(|&x| x == va);
                let sb = self.canon[u].iter().position(|&x| x == vb);
                if let (Some(sa), Some(sb)) = (sa, sb) {
                    if sa != sb {
                        out.push((u, sa, sb));
                    }
                }
            }
        }
        out
    }

    /// Rule 1: no entity of `e` already in the triangle's list.
    fn rule1(&self, st: &TriState, e: &[u32; 3]) -> bool {
        (0..3).all(|k| e[k] == NONE || !st.used[k].contains(&e[k]))
    }

    /// Rule 2 (Algorithm 1 generalised to cyclic sequences): for every pair of slots, the new
    /// link's positions fit between the same two consecutive existing links in both sequences.
    fn rule2(&self, st: &TriState, e: &[u32; 3]) -> bool {
        for (a, b) in [(0, 1), (1, 2), (0, 2)] {
            if !self.is_real(e[a]) || !self.is_real(e[b]) {
                continue;
            }
            let ((sa, pa), (sb, pb)) = (self.info[e[a] as usize], self.info[e[b] as usize]);
            if !self.contiguous(st, a, b, e) || !self.contiguous(st, b, a, e) {
                return false;
            }
            let mut pairs: Vec<(u32, u32)> = st
                .links
                .iter()
                .filter(|l| self.is_real(l.e[a]) && self.is_real(l.e[b]))
                .map(|l| (self.info[l.e[a] as usize], self.info[l.e[b] as usize]))
                .filter(|(x, y)| x.0 == sa && y.0 == sb)
                .map(|(x, y)| (x.1, y.1))
                .collect();
            if pairs.len() < 2 {
                continue;
            }
            pairs.sort_unstable();
            let (la, lb) = (self.seq_len(sa), self.seq_len(sb));
            let n = pairs.len();
            let m = |x: u32, y: u32, l: u32| (x + l - y) % l;
            let mut spans_b: Vec<u32> = (0..n - 1).map(|j| m(pairs[j + 1].1, pairs[j].1, lb)).collect();
            let wrap_b = m(pairs[0].1, pairs[n - 1].1, lb);
            let sum_b: u32 = spans_b.iter().sum::<u32>() + wrap_b;
            spans_b.push(if sum_b == 0 { lb } else { wrap_b });
            let mut spans_a: Vec<u32> = (0..n - 1).map(|j| pairs[j + 1].0 - pairs[j].0).collect();
            spans_a.push(la - (pairs[n - 1].0 - pairs[0].0));
            let fits = (0..n).any(|j| m(pa, pairs[j].0, la) <= spans_a[j] && m(pb, pairs[j].1, lb) <= spans_b[j]);
            if !fits {
                return false;
            }
        }
        true
    }

    /// Runs: along the sequence of `e[b]`, the links of each sequence of slot `a` form one
    /// contiguous run (a region linked to two regions of another vertex is split into two arcs,
    /// not interleaved); `e` must not land strictly inside the run of another sequence.
    fn contiguous(&self, st: &TriState, a: usize, b: usize, e: &[u32; 3]) -> bool {
        let ((sa, _), (sb, pb)) = (self.info[e[a] as usize], self.info[e[b] as usize]);
        let tag = |g: u32| if self.is_real(g) { self.info[g as usize].0 } else { VIRTUAL_KEY | g };
        let mut runs: Vec<(u32, u32)> = st
            .links
            .iter()
            .filter(|l| self.is_real(l.e[b]) && l.e[a] != NONE && self.info[l.e[b] as usize].0 == sb)
            .map(|l| (self.info[l.e[b] as usize].1, tag(l.e[a])))
            .collect();
        if runs.len() < 2 {
            return true;
        }
        if runs.iter().any(|&(p, s)| p == pb && s == sa) {
            return true;
        }
        runs.sort_unstable();
        let next = runs.iter().position(|&(p, _)| p > pb).unwrap_or(0);
        let prev = (next + runs.len() - 1) % runs.len();
        let (sp, sn) = (runs[prev].1, runs[next].1);
        !(sp == sn && sp != sa)
    }

    fn has_pair(&self, st: &TriState, e: &[u32; 3]) -> bool {
        st.links.iter().any(|l| (0..3).all(|k| e[k] == NONE || l.e[k] == e[k]))
    }
}

/// Orders the links of one group along the sequences they link: by the position in the real
/// slot with the most distinct entities, ties (several links on one entity, from the relaxed
/// stage) by the other slots' positions unwrapped from the previous tie group's.
fn order_loop(ctx: &Ctx, mut v: Vec<[u32; 3]>, key: [u32; 3]) -> Vec<[u32; 3]> {
    let real: Vec<usize> = (0..3).filter(|&k| key[k] & VIRTUAL_KEY == 0).collect();
    let pos = |e: &[u32; 3], k: usize| ctx.info[e[k] as usize].1;
    let distinct = |k: usize| {
        let mut p: Vec<u32> = v.iter().map(|e| pos(e, k)).collect();
        p.sort_unstable();
        p.dedup();
        p.len()
    };
    let Some(&primary) = real.iter().max_by_key(|&&k| (distinct(k), std::cmp::Reverse(k))) else { return v };
    let others: Vec<usize> = real.iter().copied().filter(|&k| k != primary).collect();
    v.sort_by_key(|e| pos(e, primary));
    let len = |k: usize| ctx.seq_len(key[k]);
    let mut out: Vec<[u32; 3]> = Vec::with_capacity(v.len());
    let mut i = 0;
    // reference positions: the last link's (the cyclically previous group)
    let mut refp: Vec<u32> = others.iter().map(|&k| v.last().map_or(0, |e| pos(e, k))).collect();
    while i < v.len() {
        let p = pos(&v[i], primary);
        let j = (i..v.len()).find(|&j| pos(&v[j], primary) != p).unwrap_or(v.len());
        let mut group = v[i..j].to_vec();
        group.sort_by_key(|e| {
            others.iter().zip(&refp).map(|(&k, &r)| (pos(e, k) + len(k) - r % len(k)) % len(k)).collect::<Vec<u32>>()
        });
        if let Some(last) = group.last() {
            refp = others.iter().map(|&k| pos(last, k)).collect();
        }
        out.extend(group);
        i = j;
    }
    out
}

fn add(st: &mut TriState, e: [u32; 3], kind: Kind) -> usize {
    for (used, g) in st.used.iter_mut().zip(e) {
        if g != NONE && !used.contains(&g) {
            used.push(g);
        }
    }
    st.links.push(Link { e, kind });
    st.links.len() - 1
}

/// Seeded splitmix64.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e3779b97f4a7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
        z ^ (z >> 31)
    }
}

/// Tripoint distance (eq. 22).
pub fn tripoint_distance(a: Vec3, b: Vec3, c: Vec3) -> f32 {
    let ang = |x: Vec3, y: Vec3| x.dot(y).clamp(-1.0, 1.0).acos();
    ang(a, b) + ang(b, c) + ang(c, a)
}

/// RGB-tripoint candidate triples of one triangle, given the entities of its three vertices
/// and their directions at the centre, best (smallest eq. 22) first.
pub fn rgb_tripoints(ents: &[Vec<u32>; 3], dirs: &[Vec<Vec3>; 3], seed: u64, cos_link: f32) -> Vec<([u32; 3], f32)> {
    if ents.iter().any(|e| e.is_empty()) {
        return Vec::new();
    }
    let mut all: Vec<glam::DVec3> = Vec::new();
    let mut who: Vec<(usize, usize)> = Vec::new();
    for k in 0..3 {
        for (i, d) in dirs[k][..ents[k].len()].iter().enumerate() {
            all.push(d.as_dvec3());
            who.push((k, i));
        }
    }
    let sites = hull::sites(&all, seed);
    let faces = hull::convex_hull(&sites.dirs);
    let mut out: Vec<([u32; 3], f32)> = Vec::new();
    for f in faces {
        let mut by: [Vec<usize>; 3] = Default::default();
        for &u in &f {
            for &m in &sites.members[u] {
                let (k, i) = who[m];
                if !by[k].contains(&i) {
                    by[k].push(i);
                }
            }
        }
        if by.iter().any(|b| b.is_empty()) {
            continue;
        }
        // every colour combination of the face's (merged) sites, best MAX_COMBOS kept
        let mut combos: Vec<([u32; 3], f32)> = Vec::new();
        for &r in by[0].iter().take(4) {
            for &g in by[1].iter().take(4) {
                for &b in by[2].iter().take(4) {
                    let (dr, dg, db) = (dirs[0][r], dirs[1][g], dirs[2][b]);
                    if dr.dot(dg) >= cos_link && dg.dot(db) >= cos_link && db.dot(dr) >= cos_link {
                        combos.push(([ents[0][r], ents[1][g], ents[2][b]], tripoint_distance(dr, dg, db)));
                    }
                }
            }
        }
        combos.sort_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
        out.extend(combos.into_iter().take(MAX_COMBOS));
    }
    out.sort_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
    out.dedup_by(|x, y| x.0 == y.0);
    out
}

/// Builds the output triple lists of every triangle; appends virtual points to `vis.points`.
/// `progress(n)` is called with finished-triangle increments (total = 2 x triangle count).
pub fn correspondence(
    model: &VvModel,
    topo: &Topology,
    vis: &mut VectorizedVisibility,
    params: &VvParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<(Correspondence, VvStats), String> {
    let ntri = model.triangle_count();
    let canon: Vec<[u32; 3]> =
        model.indices.chunks_exact(3).map(|t| [0, 1, 2].map(|k| topo.canon[t[k] as usize])).collect();
    let mut adj: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (t, c) in canon.iter().enumerate() {
        if c[0] == c[1] || c[1] == c[2] || c[0] == c[2] {
            continue;
        }
        for k in 0..3 {
            let (a, b) = (c[k], c[(k + 1) % 3]);
            adj.entry((a.min(b), a.max(b))).or_default().push(t as u32);
        }
    }
    let centre: Vec<(Vec3, Vec3)> = model
        .indices
        .chunks_exact(3)
        .map(|t| {
            let p = [0, 1, 2].map(|k| model.positions[t[k] as usize]);
            let n = [0, 1, 2].map(|k| model.normals[t[k] as usize]);
            let face = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
            let nn = (n[0] + n[1] + n[2]).try_normalize().unwrap_or(face);
            ((p[0] + p[1] + p[2]) / 3.0, nn)
        })
        .collect();
    let mut info = vec![(0u32, 0u32); vis.vertex_points as usize];
    for s in 0..vis.sequence_count() {
        let (a, b) = (vis.seq_offsets[s], vis.seq_offsets[s + 1]);
        for g in a..b {
            info[g as usize] = (s as u32, g - a);
        }
    }
    let cos_link = params.max_link_deg.to_radians().cos();
    let ctx =
        Ctx { vis: VectorizedVisibility { points: Vec::new(), ..vis.clone() }, info, canon, adj, centre, cos_link };
    let mut points = std::mem::take(&mut vis.points);
    let mut stats = VvStats::default();

    // 1. candidates per triangle
    let cands: Vec<Vec<([u32; 3], f32)>> = (0..ntri)
        .into_par_iter()
        .map(|t| {
            let ents: [Vec<u32>; 3] = [0, 1, 2].map(|k| ctx.entities(t, k).collect());
            let dirs: [Vec<Vec3>; 3] = [0, 1, 2].map(|k| ents[k].iter().map(|&g| ctx.dir(t, &points, g)).collect());
            let c = rgb_tripoints(&ents, &dirs, params.seed ^ (t as u64).wrapping_mul(0x2545f4914f6cdd1d), cos_link);
            progress(1);
            c
        })
        .collect();

    // 2. selection with Rules 1 and 2 and partial triples to the adjacent triangles
    let mut st = vec![TriState::default(); ntri];
    let mut cursor = vec![0usize; ntri];
    let mut active: Vec<usize> = (0..ntri).filter(|&t| !cands[t].is_empty()).collect();
    let mut rng = Rng(params.seed);
    let mut queue: VecDeque<(usize, usize)> = VecDeque::new();
    while !active.is_empty() {
        let i = (rng.next() % active.len() as u64) as usize;
        let t = active[i];
        let (e, _) = cands[t][cursor[t]];
        cursor[t] += 1;
        if cursor[t] == cands[t].len() {
            active.swap_remove(i);
        }
        if !ctx.rule1(&st[t], &e) || !ctx.rule2(&st[t], &e) {
            continue;
        }
        let mut partials = Vec::new();
        let mut ok = true;
        'edges: for (a, b) in [(0, 1), (1, 2), (2, 0)] {
            for (u, sa, sb) in ctx.across(t, a, b) {
                let mut pe = [NONE; 3];
                pe[sa] = e[a];
                pe[sb] = e[b];
                if ctx.has_pair(&st[u], &pe) {
                    continue;
                }
                if !ctx.rule1(&st[u], &pe) || !ctx.rule2(&st[u], &pe) {
                    ok = false;
                    break 'edges;
                }
                partials.push((u, pe));
            }
        }
        if !ok {
            continue;
        }
        add(&mut st[t], e, Kind::Voronoi);
        stats.voronoi_triples += 1;
        for (u, pe) in partials {
            let id = add(&mut st[u], pe, Kind::Partial);
            queue.push_back((u, id));
        }
    }

    // 3. complete and propagate partial triples
    while let Some((t, id)) = queue.pop_front() {
        let e = st[t].links[id].e;
        let Some(c) = (0..3).find(|&k| e[k] == NONE) else { continue };
        let Some(x) = best_completion(&ctx, &points, &st[t], t, e, c, true, None) else { continue };
        let mut full = e;
        full[c] = x;
        st[t].links[id] = Link { e: full, kind: Kind::Propagated };
        st[t].used[c].push(x);
        stats.propagated_triples += 1;
        for (a, b) in [(0, 1), (1, 2), (2, 0)] {
            if a != c && b != c {
                continue;
            }
            for (u, sa, sb) in ctx.across(t, a, b) {
                let mut pe = [NONE; 3];
                pe[sa] = full[a];
                pe[sb] = full[b];
                if ctx.has_pair(&st[u], &pe) || !ctx.rule1(&st[u], &pe) || !ctx.rule2(&st[u], &pe) {
                    continue;
                }
                let id = add(&mut st[u], pe, Kind::Partial);
                queue.push_back((u, id));
            }
        }
    }

    // 4. relaxed constraints (Rule 1 ignored, no propagation), per triangle. Triangles are
    // independent here (each completes its own list): they run in parallel, each collecting its
    // new virtual points under provisional ids (TMP_VIRTUAL + i), which are then numbered in
    // triangle order, as a sequential pass would.
    let relaxed: Vec<(u64, Vec<[f32; 4]>)> = st
        .par_iter_mut()
        .enumerate()
        .map(|(t, st_t)| {
            let mut local: Vec<[f32; 4]> = Vec::new();
            let mut virt: HashMap<(usize, u32), u32> = HashMap::new();
            let mut relaxed = 0u64;
            relax_triangle(&ctx, &points, st_t, t, &mut local, &mut virt, &mut relaxed);
            progress(1);
            (relaxed, local)
        })
        .collect();
    for (t, (relaxed, local)) in relaxed.into_iter().enumerate() {
        stats.relaxed_triples += relaxed as usize;
        if local.is_empty() {
            continue;
        }
        let base = points.len() as u32;
        points.extend_from_slice(&local);
        for l in &mut st[t].links {
            for g in &mut l.e {
                if *g != NONE && *g >= TMP_VIRTUAL {
                    *g = base + (*g - TMP_VIRTUAL);
                }
            }
        }
        for u in &mut st[t].used {
            for g in u.iter_mut() {
                if *g != NONE && *g >= TMP_VIRTUAL {
                    *g = base + (*g - TMP_VIRTUAL);
                }
            }
        }
    }

    // one pole point per canonical vertex (its unit normal, a direction): jumps are routed
    // through it (step 6)
    let mut poles: HashMap<u32, u32> = HashMap::new();

    // 5. loops
    let mut corr = Correspondence { tri_offsets: vec![0], loop_offsets: vec![0], triples: Vec::new() };
    for (t, tst) in st[..ntri].iter().enumerate() {
        let mut loops: Vec<Vec<[u32; 3]>> = Vec::new();
        let mut groups: Vec<([u32; 3], Vec<[u32; 3]>)> = Vec::new();
        for l in &tst.links {
            if l.e.contains(&NONE) {
                continue;
            }
            let key = l.e.map(|g| {
                if ctx.is_real(g) {
                    ctx.info[g as usize].0
                } else {
                    VIRTUAL_KEY | (g - ctx.vis.vertex_points)
                }
            });
            match groups.iter_mut().find(|(k, _)| *k == key) {
                Some((_, v)) => v.push(l.e),
                None => groups.push((key, vec![l.e])),
            }
        }
        groups.sort_by_key(|g| g.0);
        for (key, mut v) in groups {
            if v.len() < 3 {
                continue;
            }
            v.sort_unstable();
            v.dedup();
            let v = order_loop(&ctx, v, key);
            if v.len() < 3 {
                continue;
            }
            loops.push(v);
        }
        // 6. jumps through the pole
        let pole: [u32; 3] = [0, 1, 2].map(|k| {
            let c = ctx.canon[t][k];
            *poles.entry(c).or_insert_with(|| {
                let n = model.normals[c as usize];
                points.push([n.x, n.y, n.z, 0.0]);
                points.len() as u32 - 1
            })
        });
        stats.pole_triples += route_jumps(&ctx.vis, &ctx.info, &mut loops, pole);
        for v in loops {
            corr.triples.extend_from_slice(&v);
            corr.loop_offsets.push(corr.triples.len() as u32);
        }
        corr.tri_offsets.push(corr.loop_offsets.len() as u32 - 1);
    }
    vis.points = points;
    Ok((corr, stats))
}

/// Step 4 for one triangle: its remaining partial triples completed and every entity not yet in
/// a triple given one, Rule 1 relaxed, no propagation. New virtual points go to `local`
/// (provisional ids `TMP_VIRTUAL + i`); `relaxed` counts the triples completed or added.
fn relax_triangle(
    ctx: &Ctx,
    points: &[[f32; 4]],
    st: &mut TriState,
    t: usize,
    local: &mut Vec<[f32; 4]>,
    virt: &mut HashMap<(usize, u32), u32>,
    relaxed: &mut u64,
) {
    let ents: [Vec<u32>; 3] = [0, 1, 2].map(|k| ctx.entities(t, k).collect());
    for id in 0..st.links.len() {
        let e = st.links[id].e;
        let Some(c) = (0..3).find(|&k| e[k] == NONE) else { continue };
        let x = match best_completion(ctx, points, st, t, e, c, false, None) {
            Some(x) => x,
            None => virtual_point(ctx, points, local, virt, t, c, &e),
        };
        let mut full = e;
        full[c] = x;
        if st.links[id].kind == Kind::Partial {
            *relaxed += 1;
        }
        st.links[id] = Link { e: full, kind: Kind::Relaxed };
        if !st.used[c].contains(&x) {
            st.used[c].push(x);
        }
    }
    for k in 0..3 {
        // walk each sequence of slot k cyclically from a covered entity: an uncovered entity
        // joins the group of its predecessor along the sequence (contiguous runs, so a
        // region split between groups is cut into arcs, not counted twice)
        let mut seqs: Vec<u32> = ents[k].iter().map(|&g| ctx.info[g as usize].0).collect();
        seqs.dedup();
        for sq in seqs {
            let run: Vec<u32> = ents[k].iter().copied().filter(|&g| ctx.info[g as usize].0 == sq).collect();
            let start = run.iter().position(|g| st.used[k].contains(g)).map_or(0, |i| i + 1);
            for step in 0..run.len() {
                let g = run[(start + step) % run.len()];
                if st.used[k].contains(&g) {
                    continue;
                }
                let prev = run[(start + step + run.len() - 1) % run.len()];
                let pred = st.links.iter().rev().find(|l| l.e[k] == prev && !l.e.contains(&NONE)).map(|l| l.e);
                let mut e = [NONE; 3];
                e[k] = g;
                match pred {
                    Some(p) => {
                        for c in [(k + 1) % 3, (k + 2) % 3] {
                            if !ctx.is_real(p[c]) {
                                e[c] = p[c];
                            }
                        }
                        for c in [(k + 1) % 3, (k + 2) % 3] {
                            if e[c] == NONE {
                                let only = ctx.info[p[c] as usize].0;
                                e[c] = best_completion(ctx, points, st, t, e, c, false, Some(only)).unwrap_or(p[c]);
                            }
                        }
                    }
                    None => {
                        // real entities first (either order), then virtual points keyed by
                        // the lowest real slot (one virtual point per group)
                        for c in [(k + 1) % 3, (k + 2) % 3, (k + 1) % 3] {
                            if e[c] == NONE {
                                if let Some(x) = best_completion(ctx, points, st, t, e, c, false, None) {
                                    e[c] = x;
                                }
                            }
                        }
                        for c in [(k + 1) % 3, (k + 2) % 3] {
                            if e[c] == NONE {
                                e[c] = virtual_point(ctx, points, local, virt, t, c, &e);
                            }
                        }
                    }
                }
                add(st, e, Kind::Relaxed);
                *relaxed += 1;
            }
        }
    }
}

/// Step 6: at each vertex `k` of the triangle, the loops' slot-`k` entities must give back the
/// vertex's own loops. A region split between groups (an arc of a sequence per group, often a
/// horizon ring whose arcs interleave) would be closed by chords: along the horizon a chord
/// between two horizon points is a horizon arc whose way round is the shorter one, so a group
/// holding two arcs of a ring winds once around the normal (2 pi) — the winding flips of
/// issue 9. Instead every step of slot `k` that is not an edge `i -> i + 1` of the vertex's
/// sequence (a jump, a backward step, or an edge already taken by another loop) is routed
/// through the vertex's pole `n_k` by a triple whose slot `k` is the pole and whose other slots
/// repeat the previous triple's (zero-length steps there). At vertex `k` a loop is then a sum
/// of fan triangles `(n_k, a_i, a_i+1)` over the edges it owns; every edge of a sequence that
/// some loop of the triangle uses is owned by exactly one loop (missing edges are inserted
/// after their first entity, or before their second), so the loops add up to the vertex's own visibility exactly (the
/// fan decomposition of its loops).
///
/// `vis` gives the sequences (`seq_offsets`, `vertex_points`; its points are not read), `info`
/// each vertex point's (sequence, position), `pole` the pole point of each slot's vertex.
/// Returns the number of triples added.
pub fn route_jumps(
    vis: &VectorizedVisibility,
    info: &[(u32, u32)],
    loops: &mut [Vec<[u32; 3]>],
    pole: [u32; 3],
) -> usize {
    let is_real = |g: u32| g < vis.vertex_points;
    let succ = |g: u32| {
        let (s, p) = info[g as usize];
        let (lo, hi) = (vis.seq_offsets[s as usize], vis.seq_offsets[s as usize + 1]);
        lo + (p + 1) % (hi - lo)
    };
    let mut added = 0;
    for k in 0..3 {
        let mut owned: std::collections::HashSet<u32> = std::collections::HashSet::new();
        let mut seqs: Vec<u32> = Vec::new();
        for v in loops.iter_mut() {
            if !is_real(v[0][k]) {
                continue;
            }
            let s = info[v[0][k] as usize].0;
            if !seqs.contains(&s) {
                seqs.push(s);
            }
            let m = v.len();
            let mut out = Vec::with_capacity(m + 4);
            for i in 0..m {
                let (a, b) = (v[i][k], v[(i + 1) % m][k]);
                out.push(v[i]);
                if a == b || !is_real(a) || !is_real(b) {
                    continue;
                }
                if b == succ(a) && owned.insert(a) {
                    continue;
                }
                let mut x = v[i];
                x[k] = pole[k];
                out.push(x);
                added += 1;
            }
            *v = out;
        }
        // edges no loop owns: after the first triple holding `g` (else before `succ(g)`'s)
        // (repeated: an edge whose two entities are both missing is placed once a neighbouring
        // edge has brought one of them in)
        let mut todo: Vec<u32> = Vec::new();
        for &s in &seqs {
            todo.extend((vis.seq_offsets[s as usize]..vis.seq_offsets[s as usize + 1]).filter(|g| !owned.contains(g)));
        }
        let mut progress = true;
        while progress && !todo.is_empty() {
            progress = false;
            for g in std::mem::take(&mut todo) {
                let h = succ(g);
                let find = |x: u32| {
                    loops.iter().enumerate().find_map(|(li, v)| v.iter().position(|e| e[k] == x).map(|i| (li, i)))
                };
                if let Some((li, i)) = find(g) {
                    let (mut e, mut p) = (loops[li][i], loops[li][i]);
                    e[k] = h;
                    p[k] = pole[k];
                    loops[li].splice(i + 1..i + 1, [e, p]);
                } else if let Some((li, i)) = find(h) {
                    let (mut e, mut p) = (loops[li][i], loops[li][i]);
                    e[k] = g;
                    p[k] = pole[k];
                    loops[li].splice(i..i, [p, e]);
                } else {
                    todo.push(g);
                    continue;
                }
                owned.insert(g);
                progress = true;
                added += 2;
            }
        }
    }
    added
}

/// Best entity for the empty slot `c` of the partial link `e` in triangle `t`: Rule 2 (and Rule
/// 1 when `strict`) hold, every real pair within `max_link_deg`, smallest eq. 22.
fn best_completion(
    ctx: &Ctx,
    points: &[[f32; 4]],
    st: &TriState,
    t: usize,
    e: [u32; 3],
    c: usize,
    strict: bool,
    only: Option<u32>,
) -> Option<u32> {
    let filled_k: Vec<usize> = (0..3).filter(|&k| k != c && ctx.is_real(e[k])).collect();
    let filled: Vec<Vec3> = filled_k.iter().map(|&k| ctx.dir(t, points, e[k])).collect();
    if filled.is_empty() {
        return None;
    }
    // sequences of slot c already linked (in this triangle) to the sequences of the filled
    // entities: in the relaxed stage, they may be linked beyond the angle cap
    let linked: Vec<u32> = if strict {
        Vec::new()
    } else {
        let seqs: Vec<(usize, u32)> = filled_k.iter().map(|&k| (k, ctx.info[e[k] as usize].0)).collect();
        let mut v: Vec<u32> = st
            .links
            .iter()
            .filter(|l| {
                ctx.is_real(l.e[c])
                    && seqs.iter().any(|&(k, s)| ctx.is_real(l.e[k]) && ctx.info[l.e[k] as usize].0 == s)
            })
            .map(|l| ctx.info[l.e[c] as usize].0)
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    // the candidates passing the cheap filters, best first (near ones, then by eq. 22; ties in
    // sequence order), then the first that keeps Rule 2: the same choice as testing Rule 2 on
    // every improvement, with fewer of its (costly) tests
    let mut cands: Vec<(bool, f32, u32)> = Vec::new();
    for x in ctx.entities(t, c) {
        if strict && st.used[c].contains(&x) {
            continue;
        }
        // relaxed reuse stays within one group: `x` must not be linked to other sequences of
        // the filled slots (else a merged region would be counted once per group)
        if !strict
            && st.links.iter().any(|l| {
                l.e[c] == x
                    && filled_k
                        .iter()
                        .any(|&k| ctx.is_real(l.e[k]) && ctx.info[l.e[k] as usize].0 != ctx.info[e[k] as usize].0)
            })
        {
            continue;
        }
        if only.is_some_and(|s| ctx.info[x as usize].0 != s) {
            continue;
        }
        let d = ctx.dir(t, points, x);
        let near = filled.iter().all(|f| f.dot(d) >= ctx.cos_link);
        if !near && only.is_none() && !linked.contains(&ctx.info[x as usize].0) {
            continue;
        }
        let cost = filled.iter().map(|f| f.dot(d).clamp(-1.0, 1.0).acos()).sum::<f32>();
        cands.push((!near, cost, x));
    }
    // total order even with a NaN cost (a partial order can make sort_by panic)
    cands.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    cands.into_iter().map(|(_, _, x)| x).find(|&x| {
        let mut full = e;
        full[c] = x;
        ctx.rule2(st, &full)
    })
}

/// The virtual point standing for slot `c` of triangle `t` next to the sequence of the first
/// real entity of `e`: the mean of that sequence's points (a position when all are positions,
/// else the mean direction at the centre), so the loop collapses to it at vertex `c`.
fn virtual_point(
    ctx: &Ctx,
    points: &[[f32; 4]],
    local: &mut Vec<[f32; 4]>,
    virt: &mut HashMap<(usize, u32), u32>,
    t: usize,
    c: usize,
    e: &[u32; 3],
) -> u32 {
    let g = (0..3).filter(|&k| k != c).map(|k| e[k]).find(|&g| ctx.is_real(g)).expect("a link has a real entity");
    let s = ctx.info[g as usize].0;
    if let Some(&v) = virt.get(&(c, s)) {
        return v;
    }
    let seq: Vec<[f32; 4]> =
        points[ctx.vis.seq_offsets[s as usize] as usize..ctx.vis.seq_offsets[s as usize + 1] as usize].to_vec();
    let q = if seq.iter().all(|q| q[3] == 1.0) {
        let m = seq.iter().fold(Vec3::ZERO, |a, q| a + Vec3::new(q[0], q[1], q[2])) / seq.len() as f32;
        [m.x, m.y, m.z, 1.0]
    } else {
        let (cc, n) = ctx.centre[t];
        let m = seq.iter().fold(Vec3::ZERO, |a, q| a + synth_dir(*q, cc).unwrap_or(n)).try_normalize().unwrap_or(n);
        [m.x, m.y, m.z, 0.0]
    };
    let id = TMP_VIRTUAL + local.len() as u32;
    local.push(q);
    virt.insert((c, s), id);
    id
}
