//! Exact Euclidean nearest neighbour by brute force: a fast f32 screening pass, then an f64
//! re-check of every candidate that the screening cannot rule out.
//!
//! # Screening distances
//! The database rows `b_j` (f64) are centred by their mean `μ` (distances do not change) and
//! rounded to f32: `b̃_j = fl32(b_j − μ)`; queries likewise. f32 gemm gives dot products and
//!
//! ```text
//! d̃²(q, b_j) = ‖q̃‖² + ‖b̃_j‖² − 2 q̃·b̃_j          (f32)
//! ```
//!
//! The error of `d̃²` against the exact `d² = ‖q − b_j‖²` is at most
//! `E(q) = 2(D + 8)·u·(‖q̃‖ + max_j ‖b̃_j‖)²` with `u = 2⁻²⁴` and `D` the dimension: rounding the
//! centred vectors to f32 moves a distance by at most `u(‖q̃‖ + ‖b̃‖)`, and an f32 dot product of
//! length D in any summation order errs by at most `γ_D Σ|q_i b_i|` (Higham, Thm 3.1); the
//! factor 2 is spare.
//!
//! # Lower bounds (large databases)
//! With an orthonormal basis `U` (`r × D`, r = 32) of the rows' principal subspace (subspace
//! iteration on the second-moment matrix of up to 8,192 rows), every row stores its projection
//! `U b̃` and residual norm `h(b̃) = ‖b̃ − Uᵀ U b̃‖`. For any q and b
//!
//! ```text
//! LB²(q, b) = ‖U q̃ − U b̃‖² + (h(q̃) − h(b̃))²  ≤  ‖q̃ − b̃‖²
//! ```
//!
//! (Pythagoras plus the reverse triangle inequality), at an r-dimensional cost (f32 gemm; the
//! residual norms come from f64 projections, so their cancellation error stays far below
//! `u·‖b̃‖`); its f32 error is well below `E(q)`. Rows are bounded chunk by chunk; in each
//! chunk the row with the smallest bound is screened first, then every row whose bound is
//! within `2E(q)` of the best screening distance so far. Any other row is strictly farther
//! than that best row in exact arithmetic, so it cannot be the answer. On real motion words
//! 32 dimensions hold ~99% of the variance and only a handful of rows per query get screened.
//! Without a basis (small or low-dimensional databases) every row is screened by gemm.
//!
//! # Exact answer
//! Every row whose screening distance is within `2E(q)` of the smallest one is a candidate;
//! the exact nearest row is always among them, because any row beyond that margin is farther
//! than the screened minimum's row even in exact arithmetic. The candidates are re-checked
//! with the caller's exact f64 distance and the smallest wins; ties go to the lowest index.
//! The result is therefore exactly the f64 brute-force answer.

use crate::{bail, Result};
use gemm::Parallelism;
use rand::{rngs::StdRng, Rng, SeedableRng};
use rayon::prelude::*;

/// Queries per parallel task.
const QUERY_BLOCK: usize = 128;
/// Database rows per gemm call.
const ROW_CHUNK: usize = 2048;
/// Unit roundoff of f32.
const U32: f64 = 1.0 / (1u64 << 24) as f64;
/// Dimension of the lower-bound subspace.
const LOW_DIM: usize = 32;
/// Rows below which no lower-bound basis is built (brute force is as fast).
const MIN_ROWS_FOR_BOUNDS: usize = 4096;

/// The nearest database row of a query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbour {
    /// Row index in the database.
    pub index: usize,
    /// Exact squared Euclidean distance (f64).
    pub dist2: f64,
}

/// Whether [`ExactNn`] builds the lower-bound basis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bounds {
    /// When the database has at least 4,096 rows and dimension above 64.
    Auto,
    /// Never: every row is screened by gemm.
    Never,
    /// Always (when the dimension exceeds the subspace's).
    Always,
}

/// The principal-subspace data of the lower bounds.
#[derive(Clone, Debug)]
struct LowerBounds {
    /// Orthonormal basis `[LOW_DIM, dim]`, f64.
    basis: Vec<f64>,
    /// Projections of the f32 rows, rounded to f32, `[len, LOW_DIM]`.
    low: Vec<f32>,
    /// Squared norms of the f32 projections, `[len]`.
    low_n2: Vec<f32>,
    /// Residual norms `[len]`.
    resid: Vec<f32>,
}

/// A database of `len` rows of dimension `dim` prepared for exact nearest-neighbour search.
///
/// Stores the centred f32 copy (`4·len·dim` bytes) and, for large databases, `4·len·33` bytes
/// of lower-bound data; the exact f64 rows stay with the caller, who supplies the exact distance
/// to [`ExactNn::search`].
#[derive(Clone, Debug)]
pub struct ExactNn {
    dim: usize,
    len: usize,
    mean: Vec<f64>,
    /// Centred rows rounded to f32, `[len, dim]`.
    rows: Vec<f32>,
    /// Squared norms of the f32 rows (computed in f64, rounded), `[len]`.
    norms2: Vec<f32>,
    /// Largest norm of an f32 row (f64).
    max_norm: f64,
    bounds: Option<LowerBounds>,
}

/// Per-block query data.
struct QueryBlock {
    nq: usize,
    /// Centred f32 queries `[nq, dim]`.
    qc: Vec<f32>,
    qn2: Vec<f32>,
    margin: Vec<f32>,
    finite: Vec<bool>,
}

/// Running screening state of one query.
#[derive(Clone)]
struct Screen {
    best: f32,
    cands: Vec<(f32, u32)>,
}

impl Screen {
    fn new() -> Self {
        Self { best: f32::INFINITY, cands: Vec::new() }
    }

    /// Records screening distance `x` of row `j`.
    #[inline]
    fn offer(&mut self, x: f32, j: usize, margin: f32) {
        if x <= self.best + margin {
            self.cands.push((x, j as u32));
            if x < self.best {
                self.best = x;
            }
            if self.cands.len() > 512 {
                let thr = self.best + margin;
                self.cands.retain(|&(x, _)| x <= thr);
            }
        }
    }
}

impl ExactNn {
    /// Builds the index from `len` rows of dimension `dim`; `fill(i, out)` writes row `i`
    /// (f64, `out.len() == dim`). `fill` is called twice per row (once for the mean), in
    /// parallel. Non-finite values are an error naming the row.
    pub fn build(len: usize, dim: usize, fill: impl Fn(usize, &mut [f64]) + Sync) -> Result<Self> {
        Self::build_with(len, dim, fill, Bounds::Auto)
    }

    /// [`ExactNn::build`] with a choice of lower bounds.
    pub fn build_with(len: usize, dim: usize, fill: impl Fn(usize, &mut [f64]) + Sync, bounds: Bounds) -> Result<Self> {
        if dim == 0 {
            bail!("nearest-neighbour index: dimension 0");
        }
        // Mean: fixed chunks summed in order (deterministic for any thread count).
        const CH: usize = 4096;
        let partial: Vec<Result<Vec<f64>>> = (0..len.div_ceil(CH))
            .into_par_iter()
            .map(|c| {
                let mut acc = vec![0.0; dim];
                let mut buf = vec![0.0; dim];
                for i in c * CH..((c + 1) * CH).min(len) {
                    fill(i, &mut buf);
                    if let Some(k) = buf.iter().position(|v| !v.is_finite()) {
                        bail!("nearest-neighbour index: row {i} has a non-finite value at dim {k}");
                    }
                    acc.iter_mut().zip(&buf).for_each(|(a, b)| *a += b);
                }
                Ok(acc)
            })
            .collect();
        let mut mean = vec![0.0; dim];
        for p in partial {
            mean.iter_mut().zip(&p?).for_each(|(a, b)| *a += b);
        }
        if len > 0 {
            mean.iter_mut().for_each(|m| *m /= len as f64);
        }
        let mut rows = vec![0f32; len * dim];
        let mut norms2 = vec![0f32; len];
        rows.par_chunks_mut(dim).zip(norms2.par_iter_mut()).enumerate().for_each_init(
            || vec![0.0; dim],
            |buf, (i, (row, n2))| {
                fill(i, buf);
                let mut s = 0.0;
                for ((r, &b), &m) in row.iter_mut().zip(buf.iter()).zip(&mean) {
                    *r = (b - m) as f32;
                    s += (*r as f64) * (*r as f64);
                }
                *n2 = s as f32;
            },
        );
        let max_norm = norms2.iter().fold(0f64, |a, &n| a.max(n as f64)).sqrt() * (1.0 + 4.0 * U32);
        let want = match bounds {
            Bounds::Auto => len >= MIN_ROWS_FOR_BOUNDS && dim > 2 * LOW_DIM,
            Bounds::Never => false,
            Bounds::Always => dim > LOW_DIM && len > 0,
        };
        let bounds = want.then(|| LowerBounds::build(&rows, len, dim));
        Ok(Self { dim, len, mean, rows, norms2, max_norm, bounds })
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the index has no rows.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether the subspace lower bounds are in use.
    pub fn has_bounds(&self) -> bool {
        self.bounds.is_some()
    }

    /// Dimension of a row.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Exact nearest row of every query (see the module docs).
    ///
    /// `exact(j, q)` must return the exact squared distance between row `j` and query `q` (the
    /// f64 values the index was built from). Rows with `allowed[j] == false` are never returned;
    /// a query gets `None` when no row is allowed or the query is not finite.
    ///
    /// # Shapes
    /// - `queries`: `[Q · dim]`, row-major; `allowed`: `[len]`; output `[Q]`.
    pub fn search(&self, queries: &[f64], allowed: Option<&[bool]>, exact: impl Fn(usize, &[f64]) -> f64 + Sync) -> Result<Vec<Option<Neighbour>>> {
        let dim = self.dim;
        if !queries.len().is_multiple_of(dim) {
            bail!("nearest-neighbour search: query buffer of {} values is not a multiple of dimension {dim}", queries.len());
        }
        if let Some(a) = allowed {
            if a.len() != self.len {
                bail!("nearest-neighbour search: allowed mask has {} entries for {} rows", a.len(), self.len);
            }
        }
        let blocks: Vec<Vec<Option<Neighbour>>> = queries
            .par_chunks(QUERY_BLOCK * dim)
            .map(|qb| {
                let block = self.prepare(qb);
                let screens = match &self.bounds {
                    Some(lb) => self.screen_bounded(lb, &block, allowed),
                    None => self.screen_all(&block, allowed),
                };
                self.finish(qb, &block, screens, &exact)
            })
            .collect();
        Ok(blocks.into_iter().flatten().collect())
    }

    fn prepare(&self, qb: &[f64]) -> QueryBlock {
        let dim = self.dim;
        let nq = qb.len() / dim;
        let mut qc = vec![0f32; nq * dim];
        let mut qn2 = vec![0f32; nq];
        let mut margin = vec![0f32; nq];
        let mut finite = vec![true; nq];
        for r in 0..nq {
            let mut s = 0.0;
            for k in 0..dim {
                let v = (qb[r * dim + k] - self.mean[k]) as f32;
                qc[r * dim + k] = v;
                s += v as f64 * v as f64;
            }
            finite[r] = s.is_finite();
            qn2[r] = s as f32;
            let bound = 2.0 * (dim as f64 + 8.0) * U32 * (s.sqrt() + self.max_norm).powi(2);
            // Candidates within 2E of the screened minimum; a little extra for the f32 compare.
            margin[r] = (2.0 * bound * (1.0 + 1e-3) + f64::from(f32::MIN_POSITIVE)) as f32;
        }
        QueryBlock { nq, qc, qn2, margin, finite }
    }

    /// Screening distance of query `r` of `block` to row `j` (f32).
    #[inline]
    fn screen_one(&self, block: &QueryBlock, r: usize, j: usize) -> f32 {
        let d = self.dim;
        block.qn2[r] + self.norms2[j] - 2.0 * dot32(&block.qc[r * d..(r + 1) * d], &self.rows[j * d..(j + 1) * d])
    }

    /// Screens every row with gemm.
    fn screen_all(&self, block: &QueryBlock, allowed: Option<&[bool]>) -> Vec<Screen> {
        let (dim, nq) = (self.dim, block.nq);
        let mut screens = vec![Screen::new(); nq];
        let mut g = vec![0f32; nq * ROW_CHUNK];
        let mut c0 = 0;
        while c0 < self.len {
            let cb = ROW_CHUNK.min(self.len - c0);
            // g[r, j] = −2 q̃_r · b̃_{c0+j}
            // SAFETY: g is nq×cb, qc nq×dim, the chunk of rows cb×dim read as dim×cb; in bounds.
            unsafe { gemm_nt(nq, cb, dim, &mut g, &block.qc, &self.rows[c0 * dim..(c0 + cb) * dim]) };
            let dn = &self.norms2[c0..c0 + cb];
            for r in 0..nq {
                if !block.finite[r] {
                    continue;
                }
                let row = &mut g[r * cb..(r + 1) * cb];
                let q = block.qn2[r];
                for (x, &d) in row.iter_mut().zip(dn) {
                    *x += q + d;
                }
                mask_row(row, allowed.map(|a| &a[c0..c0 + cb]));
                let m = row_min(row);
                let sc = &mut screens[r];
                if m == f32::INFINITY || m > sc.best + block.margin[r] {
                    continue;
                }
                for (j, &x) in row.iter().enumerate() {
                    sc.offer(x, c0 + j, block.margin[r]);
                }
            }
            c0 += cb;
        }
        screens
    }

    /// Screens the rows that the subspace lower bounds cannot rule out (module docs).
    fn screen_bounded(&self, lb: &LowerBounds, block: &QueryBlock, allowed: Option<&[bool]>) -> Vec<Screen> {
        let (dim, nq) = (self.dim, block.nq);
        // Query projections, their squared norms and residual norms.
        let mut ql = vec![0f32; nq * LOW_DIM];
        let mut qln2 = vec![0f32; nq];
        let mut qh = vec![0f32; nq];
        for r in 0..nq {
            let q = &block.qc[r * dim..(r + 1) * dim];
            let (n2, p2, p2_rounded) = lb.project(q, &mut ql[r * LOW_DIM..(r + 1) * LOW_DIM]);
            qln2[r] = p2_rounded as f32;
            qh[r] = (n2 - p2).max(0.0).sqrt() as f32;
        }
        let mut g = vec![0f32; nq * ROW_CHUNK];
        // Lower bounds of rows c0..c0+cb for every query into g.
        let bounds_into = |g: &mut [f32], c0: usize, cb: usize| {
            // SAFETY: as in screen_all, with LOW_DIM columns.
            unsafe { gemm_nt(nq, cb, LOW_DIM, g, &ql, &lb.low[c0 * LOW_DIM..(c0 + cb) * LOW_DIM]) };
            let (ln2, rh) = (&lb.low_n2[c0..c0 + cb], &lb.resid[c0..c0 + cb]);
            for r in 0..nq {
                let row = &mut g[r * cb..(r + 1) * cb];
                let (q, h) = (qln2[r], qh[r]);
                for ((x, &n), &hb) in row.iter_mut().zip(ln2).zip(rh) {
                    let dh = h - hb;
                    *x += q + n + dh * dh;
                }
                mask_row(row, allowed.map(|a| &a[c0..c0 + cb]));
            }
        };
        // One pass: per chunk, the row with the smallest bound first (a good current best),
        // then every row whose bound is within the margin of the best screening distance.
        let mut screens = vec![Screen::new(); nq];
        let mut c0 = 0;
        while c0 < self.len {
            let cb = ROW_CHUNK.min(self.len - c0);
            bounds_into(&mut g, c0, cb);
            for r in 0..nq {
                let row = &g[r * cb..(r + 1) * cb];
                let sc = &mut screens[r];
                let margin = block.margin[r];
                let m = row_min(row);
                if !block.finite[r] || m == f32::INFINITY || m > sc.best + margin {
                    continue;
                }
                let jm = row.iter().position(|&x| x == m).expect("the minimum is in the row");
                sc.offer(self.screen_one(block, r, c0 + jm), c0 + jm, margin);
                if m > sc.best + margin {
                    continue;
                }
                for (j, &x) in row.iter().enumerate() {
                    if x <= sc.best + margin && j != jm {
                        sc.offer(self.screen_one(block, r, c0 + j), c0 + j, margin);
                    }
                }
            }
            c0 += cb;
        }
        screens
    }

    /// Exact re-check of the candidates.
    fn finish(&self, qb: &[f64], block: &QueryBlock, screens: Vec<Screen>, exact: &(impl Fn(usize, &[f64]) -> f64 + Sync)) -> Vec<Option<Neighbour>> {
        let dim = self.dim;
        screens
            .into_iter()
            .enumerate()
            .map(|(r, mut sc)| {
                let thr = sc.best + block.margin[r];
                sc.cands.retain(|&(x, _)| x <= thr);
                sc.cands.sort_unstable_by_key(|c| c.1);
                sc.cands.dedup_by_key(|c| c.1);
                let q = &qb[r * dim..(r + 1) * dim];
                let mut out: Option<Neighbour> = None;
                for &(_, j) in &sc.cands {
                    let d = exact(j as usize, q);
                    if out.is_none_or(|o| d < o.dist2) {
                        out = Some(Neighbour { index: j as usize, dist2: d });
                    }
                }
                out
            })
            .collect()
    }
}

impl LowerBounds {
    /// Basis by subspace iteration on the second-moment matrix of (up to 8,192) rows, then the
    /// projection and residual norm of every row.
    fn build(rows: &[f32], len: usize, dim: usize) -> Self {
        let step = len.div_ceil(8192).max(1);
        let sample: Vec<f64> = rows.chunks_exact(dim).step_by(step).flatten().map(|&v| v as f64).collect();
        let ns = sample.len() / dim;
        let mut cov = vec![0f64; dim * dim];
        // SAFETY: cov is dim×dim, sample ns×dim; cov = sampleᵀ·sample.
        unsafe {
            gemm::gemm(
                dim,
                dim,
                ns,
                cov.as_mut_ptr(),
                1,
                dim as isize,
                false,
                sample.as_ptr(),
                dim as isize,
                1,
                sample.as_ptr(),
                1,
                dim as isize,
                0.0f64,
                1.0f64,
                false,
                false,
                false,
                Parallelism::Rayon(0),
            );
        }
        let mut rng = StdRng::seed_from_u64(0x5eed);
        let mut v: Vec<f64> = (0..LOW_DIM * dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
        orthonormalize(&mut v, dim);
        let mut w = vec![0f64; LOW_DIM * dim];
        for _ in 0..30 {
            w.par_chunks_mut(dim).zip(v.par_chunks(dim)).for_each(|(wr, vr)| {
                for (i, o) in wr.iter_mut().enumerate() {
                    *o = cov[i * dim..(i + 1) * dim].iter().zip(vr).map(|(a, b)| a * b).sum();
                }
            });
            std::mem::swap(&mut v, &mut w);
            orthonormalize(&mut v, dim);
        }
        let basis = v;
        let mut low = vec![0f32; len * LOW_DIM];
        let mut low_n2 = vec![0f32; len];
        let mut resid = vec![0f32; len];
        let lb = Self { basis, low: Vec::new(), low_n2: Vec::new(), resid: Vec::new() };
        low.par_chunks_mut(LOW_DIM).zip(low_n2.par_iter_mut().zip(resid.par_iter_mut())).zip(rows.par_chunks(dim)).for_each(|((l, (n2, h)), row)| {
            let (rn2, p2, p2_rounded) = lb.project(row, l);
            *n2 = p2_rounded as f32;
            *h = (rn2 - p2).max(0.0).sqrt() as f32;
        });
        Self { low, low_n2, resid, ..lb }
    }

    /// Writes `fl32(U x)` into `out`; returns `‖x‖²`, `‖U x‖²` (f64 projection) and
    /// `‖fl32(U x)‖²`, all summed in f64.
    fn project(&self, x: &[f32], out: &mut [f32]) -> (f64, f64, f64) {
        let dim = x.len();
        let n2: f64 = x.iter().map(|&v| v as f64 * v as f64).sum();
        let (mut p2, mut p2_rounded) = (0.0, 0.0);
        for (i, o) in out.iter_mut().enumerate() {
            let p: f64 = self.basis[i * dim..(i + 1) * dim].iter().zip(x).map(|(a, &b)| a * b as f64).sum();
            *o = p as f32;
            p2 += p * p;
            p2_rounded += (*o as f64) * (*o as f64);
        }
        (n2, p2, p2_rounded)
    }
}

/// Modified Gram–Schmidt, twice, on the rows of `v` (`[rows, dim]`).
fn orthonormalize(v: &mut [f64], dim: usize) {
    let n = v.len() / dim;
    for _ in 0..2 {
        for i in 0..n {
            for k in 0..i {
                let (a, b) = v.split_at_mut(i * dim);
                let prev = &a[k * dim..(k + 1) * dim];
                let cur = &mut b[..dim];
                let d: f64 = prev.iter().zip(cur.iter()).map(|(x, y)| x * y).sum();
                cur.iter_mut().zip(prev).for_each(|(c, p)| *c -= d * p);
            }
            let cur = &mut v[i * dim..(i + 1) * dim];
            let norm = cur.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm > 0.0 {
                cur.iter_mut().for_each(|c| *c /= norm);
            }
        }
    }
}

/// `g[r, j] = −2 · a_r · b_j` for `a` `[m, k]` and `b` `[n, k]` (row-major), single-threaded.
///
/// # Safety
/// `g` must hold `m·n` values, `a` `m·k`, `b` `n·k`.
unsafe fn gemm_nt(m: usize, n: usize, k: usize, g: &mut [f32], a: &[f32], b: &[f32]) {
    debug_assert!(g.len() >= m * n && a.len() >= m * k && b.len() >= n * k);
    gemm::gemm(
        m,
        n,
        k,
        g.as_mut_ptr(),
        1,
        n as isize,
        false,
        a.as_ptr(),
        1,
        k as isize,
        b.as_ptr(),
        k as isize,
        1,
        0.0f32,
        -2.0f32,
        false,
        false,
        false,
        Parallelism::None,
    );
}

/// Sets disallowed entries to +∞.
#[inline]
fn mask_row(row: &mut [f32], allowed: Option<&[bool]>) {
    if let Some(a) = allowed {
        for (x, &ok) in row.iter_mut().zip(a) {
            if !ok {
                *x = f32::INFINITY;
            }
        }
    }
}

/// f32 dot product with 16 independent accumulators (vectorizes).
#[inline]
fn dot32(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 16];
    let (ca, cb) = (a.chunks_exact(16), b.chunks_exact(16));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..16 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s: f32 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    for v in acc {
        s += v;
    }
    s
}

/// Minimum of a row (NaN-free input), written so that it vectorizes.
fn row_min(x: &[f32]) -> f32 {
    let mut acc = [f32::INFINITY; 16];
    let mut chunks = x.chunks_exact(16);
    for c in &mut chunks {
        for k in 0..16 {
            acc[k] = if c[k] < acc[k] { c[k] } else { acc[k] };
        }
    }
    let mut m = chunks.remainder().iter().fold(f32::INFINITY, |a, &b| if b < a { b } else { a });
    for a in acc {
        m = if a < m { a } else { m };
    }
    m
}

/// Exact squared Euclidean distance in f64, summed in index order.
pub fn dist2(a: &[f64], b: &[f64]) -> f64 {
    let mut s = 0.0;
    for (x, y) in a.iter().zip(b) {
        let d = x - y;
        s += d * d;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{rngs::StdRng, Rng, SeedableRng};

    fn naive(rows: &[f64], q: &[f64], dim: usize, allowed: Option<&[bool]>) -> Option<(usize, f64)> {
        let mut best: Option<(usize, f64)> = None;
        for (j, r) in rows.chunks_exact(dim).enumerate() {
            if allowed.is_some_and(|a| !a[j]) {
                continue;
            }
            let d = dist2(r, q);
            if best.is_none_or(|(_, b)| d < b) {
                best = Some((j, d));
            }
        }
        best
    }

    /// Exact search equals an f64 brute-force loop on data built to have near-ties: rows are
    /// few centres plus tiny offsets, far from the origin (large norms make f32 screening
    /// coarse), queries sit next to rows.
    #[test]
    fn exact_nn_matches_naive_f64_loop() {
        let mut rng = StdRng::seed_from_u64(7);
        for &(n, dim, spread) in &[(3000usize, 33usize, 1e-4f64), (2500, 330, 1e-3), (700, 5, 0.0)] {
            let centres: Vec<f64> = (0..20 * dim).map(|_| 50.0 + rng.gen_range(-1.0..1.0)).collect();
            let rows: Vec<f64> = (0..n)
                .flat_map(|i| {
                    let c = (i * 7) % 20;
                    (0..dim).map(|k| centres[c * dim + k] + spread * rng.gen_range(-1.0..1.0)).collect::<Vec<_>>()
                })
                .collect();
            for bounds in [Bounds::Never, Bounds::Always] {
                let index = ExactNn::build_with(n, dim, |i, out| out.copy_from_slice(&rows[i * dim..(i + 1) * dim]), bounds).unwrap();
                assert_eq!(index.bounds.is_some(), bounds == Bounds::Always && dim > LOW_DIM);
                let nq = 300;
                let queries: Vec<f64> = (0..nq)
                    .flat_map(|i| {
                        let j = (i * 13) % n;
                        (0..dim).map(|k| rows[j * dim + k] + spread * 0.5 * rng.gen_range(-1.0..1.0)).collect::<Vec<_>>()
                    })
                    .collect();
                let allowed: Vec<bool> = (0..n).map(|j| j % 3 != 0).collect();
                for mask in [None, Some(allowed.as_slice())] {
                    let got = index.search(&queries, mask, |j, q| dist2(&rows[j * dim..(j + 1) * dim], q)).unwrap();
                    for (i, g) in got.iter().enumerate() {
                        let want = naive(&rows, &queries[i * dim..(i + 1) * dim], dim, mask).unwrap();
                        let g = g.expect("a neighbour");
                        assert_eq!((g.index, g.dist2), want, "n {n} dim {dim} query {i} {bounds:?}");
                    }
                }
            }
        }
    }

    /// Rows almost inside a 32-dimensional subspace (residuals ~1e-6): the residual norms of
    /// the lower bounds are tiny and must not break exactness.
    #[test]
    fn exact_nn_with_bounds_on_nearly_flat_data() {
        let mut rng = StdRng::seed_from_u64(9);
        let (n, dim) = (4100, 40);
        let axes: Vec<f64> = (0..LOW_DIM * dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let rows: Vec<f64> = (0..n)
            .flat_map(|i| {
                let c: Vec<f64> = (0..LOW_DIM).map(|a| if a < 3 { rng.gen_range(-1.0..1.0) } else { ((i % 5) as f64) * 1e-3 * (a as f64) }).collect();
                (0..dim).map(|k| 10.0 + (0..LOW_DIM).map(|a| c[a] * axes[a * dim + k]).sum::<f64>() + 1e-6 * rng.gen_range(-1.0..1.0)).collect::<Vec<_>>()
            })
            .collect();
        let index = ExactNn::build_with(n, dim, |i, out| out.copy_from_slice(&rows[i * dim..(i + 1) * dim]), Bounds::Always).unwrap();
        assert!(index.has_bounds());
        let queries: Vec<f64> =
            (0..200).flat_map(|i| (0..dim).map(|k| rows[(i * 17) * dim + k] + 1e-6 * rng.gen_range(-1.0..1.0)).collect::<Vec<_>>()).collect();
        let got = index.search(&queries, None, |j, q| dist2(&rows[j * dim..(j + 1) * dim], q)).unwrap();
        for (i, g) in got.iter().enumerate() {
            let want = naive(&rows, &queries[i * dim..(i + 1) * dim], dim, None).unwrap();
            assert_eq!((g.unwrap().index, g.unwrap().dist2), want, "query {i}");
        }
    }

    #[test]
    fn no_allowed_row_gives_none() {
        let rows = [0.0, 1.0, 2.0];
        let index = ExactNn::build(3, 1, |i, o| o[0] = rows[i]).unwrap();
        let got = index.search(&[1.2, 5.0], Some(&[false; 3]), |j, q| dist2(&rows[j..j + 1], q)).unwrap();
        assert_eq!(got, vec![None, None]);
        let got = index.search(&[1.2, 5.0], None, |j, q| dist2(&rows[j..j + 1], q)).unwrap();
        assert_eq!(got[0].unwrap().index, 1);
        assert_eq!(got[1].unwrap().index, 2);
        assert!(index.search(&[1.0, 2.0], Some(&[true]), |_, _| 0.0).is_err());
        assert!(ExactNn::build(2, 1, |_, o| o[0] = f64::NAN).is_err());
    }
}
