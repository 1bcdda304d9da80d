// Particle–object collisions (ConvSDF push-out with anti-clipping pieces) for
// liquidtwin/sim/collide.py, forward and backward. Included by pbf_native.cpp, which
// registers the functions.
//
// The arithmetic computes what the torch path computes, so both agree to rounding:
// SDFGrid.sample_local (clamp to the grid box, grid_sample trilinear with align_corners and
// border padding, plus the distance to the box; here in a cheaper equal form, Grid::locate),
// quat_to_matrix / interpolate_poses (nlerp), and push_out (7-point stencil: value and
// central-difference normal of min_j SDF_j).
// Every particle is independent, so the loop parallelises over particles without atomics.
#pragma once

#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace collide {

// A signed distance grid (nx, ny, nz) in its object frame, sampled like SDFGrid.sample_local.
template <typename T>
struct Grid {
  const T* v = nullptr;
  int64_t n[3] = {0, 0, 0};
  T origin[3] = {0, 0, 0};
  T cell = 0;
  T inv_cell = 0;
  T extent[3] = {0, 0, 0};  // n - 1

  // Node index of local point p clamped to the grid box (uc), the distance components from p
  // to the box (du, m) and whether p lies strictly inside the box along each axis (inside).
  // SDFGrid.sample_local maps uc to grid_sample's [-1, 1] and grid_sample maps it back
  // (align_corners, border padding): the same index up to rounding, so it is used as it is.
  T locate(const T p[3], T uc[3], T du[3], bool inside[3]) const {
    T out2 = 0;
    for (int a = 0; a < 3; ++a) {
      const T u = (p[a] - origin[a]) * inv_cell;
      uc[a] = std::min(std::max(u, T(0)), extent[a]);
      inside[a] = u > T(0) && u < extent[a];
      du[a] = (u - uc[a]) * cell;
      out2 += du[a] * du[a];
    }
    return out2 > T(0) ? std::sqrt(out2) : T(0);
  }

  // The 8 trilinear corners of node index ix (c[x][y][z]) and the upper weights b (3,). The
  // lower corner stays one node below the top, so all 8 exist; at the top face the upper
  // corner takes weight 1 and gives grid_sample's value (and, with the clip's zero
  // derivative along that axis, its gradient).
  void corners(const T ix[3], T c[2][2][2], T b[3]) const {
    int64_t c0[3];
    for (int a = 0; a < 3; ++a) {
      c0[a] = std::min(static_cast<int64_t>(ix[a]), n[a] - 2);  // ix >= 0: truncation is floor
      b[a] = ix[a] - static_cast<T>(c0[a]);
    }
    const T* base = v + (c0[0] * n[1] + c0[1]) * n[2] + c0[2];
    const int64_t sx = n[1] * n[2], sy = n[2];
    c[0][0][0] = base[0]; c[0][0][1] = base[1]; c[0][1][0] = base[sy]; c[0][1][1] = base[sy + 1];
    c[1][0][0] = base[sx]; c[1][0][1] = base[sx + 1]; c[1][1][0] = base[sx + sy]; c[1][1][1] = base[sx + sy + 1];
  }

  // Trilinear value at the clamped point and the distance from the point to the grid box.
  void sample(const T p[3], T& val, T& outside) const {
    T ix[3], du[3];
    bool in[3];
    outside = locate(p, ix, du, in);
    val = trilinear(ix);
  }

  // The trilinear value at node index ix (clamped to the box).
  T trilinear(const T ix[3]) const {
    T c[2][2][2], b[3];
    corners(ix, c, b);
    const T az = T(1) - b[2], ay = T(1) - b[1];
    const T v00 = c[0][0][0] * az + c[0][0][1] * b[2], v01 = c[0][1][0] * az + c[0][1][1] * b[2];
    const T v10 = c[1][0][0] * az + c[1][0][1] * b[2], v11 = c[1][1][0] * az + c[1][1][1] * b[2];
    return (v00 * ay + v01 * b[1]) * (T(1) - b[0]) + (v10 * ay + v11 * b[1]) * b[0];
  }

  T value(const T p[3]) const { T v, o; sample(p, v, o); return v + o; }

  // value(p) and its derivative d value / d p (3), as autograd differentiates sample_local:
  // the clamp to the box passes gradient strictly inside it, the trilinear weights are
  // differentiated with the corners fixed, and the distance to the box has gradient
  // (u - uc) cell / |.| (0 at distance 0).
  T value_grad(const T p[3], T grad[3]) const {
    T ix[3], du[3], c[2][2][2], b[3];
    bool in[3];
    const T outside = locate(p, ix, du, in);
    corners(ix, c, b);
    const T bx = b[0], by = b[1], bz = b[2], ax = T(1) - bx, ay = T(1) - by, az = T(1) - bz;
    const T v000 = c[0][0][0], v100 = c[1][0][0], v010 = c[0][1][0], v110 = c[1][1][0];
    const T v001 = c[0][0][1], v101 = c[1][0][1], v011 = c[0][1][1], v111 = c[1][1][1];
    const T r = ((v000 * az + v001 * bz) * ay + (v010 * az + v011 * bz) * by) * ax +
                ((v100 * az + v101 * bz) * ay + (v110 * az + v111 * bz) * by) * bx;
    const T gx = (v100 - v000) * ay * az + (v110 - v010) * by * az + (v101 - v001) * ay * bz + (v111 - v011) * by * bz;
    const T gy = (v010 - v000) * ax * az + (v110 - v100) * bx * az + (v011 - v001) * ax * bz + (v111 - v101) * bx * bz;
    const T gz = (v001 - v000) * ax * ay + (v101 - v100) * bx * ay + (v011 - v010) * ax * by + (v111 - v110) * bx * by;
    const T gi[3] = {gx, gy, gz};
    for (int a = 0; a < 3; ++a) {
      grad[a] = in[a] ? gi[a] * inv_cell : T(0);
      if (outside > T(0)) grad[a] += du[a] / outside;  // du = 0 on axes inside the box
    }
    return r + outside;
  }
  T lower_bound(const T p[3]) const { T v, o; sample(p, v, o); return std::max(o, v - o); }

  // lower_bound(p) where that is below `enough`; else some value >= enough (the distance to
  // the grid box when that alone reaches it: lower_bound >= it, and the 8 corners go unread).
  T lower_bound_below(const T p[3], T enough) const {
    T ix[3], du[3];
    bool in[3];
    const T o = locate(p, ix, du, in);
    if (o >= enough) return o;
    return std::max(o, trilinear(ix) - o);
  }
};

// Rigid frame: local = R^T (p - t).
template <typename T>
struct Frame {
  T R[9];
  T t[3];
  void set(const T q_in[4], const T t_in[3]) {  // quat_to_matrix: normalises q
    T nn = std::sqrt(q_in[0] * q_in[0] + q_in[1] * q_in[1] + q_in[2] * q_in[2] + q_in[3] * q_in[3]);
    T x = q_in[0] / nn, y = q_in[1] / nn, z = q_in[2] / nn, w = q_in[3] / nn;
    R[0] = 1 - 2 * (y * y + z * z); R[1] = 2 * (x * y - z * w); R[2] = 2 * (x * z + y * w);
    R[3] = 2 * (x * y + z * w); R[4] = 1 - 2 * (x * x + z * z); R[5] = 2 * (y * z - x * w);
    R[6] = 2 * (x * z - y * w); R[7] = 2 * (y * z + x * w); R[8] = 1 - 2 * (x * x + y * y);
    for (int a = 0; a < 3; ++a) t[a] = t_in[a];
  }
  void local(const T p[3], T out[3]) const {
    T d0 = p[0] - t[0], d1 = p[1] - t[1], d2 = p[2] - t[2];
    for (int a = 0; a < 3; ++a) out[a] = d0 * R[a] + d1 * R[3 + a] + d2 * R[6 + a];
  }
};

// One Frame per row of contiguous (M, 7) poses (x, y, z, qx, qy, qz, qw) of scalar type T.
template <typename T>
std::vector<Frame<T>> make_frames(const torch::Tensor& poses) {
  const T* pp = poses.data_ptr<T>();
  std::vector<Frame<T>> frames(poses.size(0));
  for (int64_t j = 0; j < poses.size(0); ++j) frames[j].set(pp + 7 * j + 3, pp + 7 * j);
  return frames;
}

// Object motion from pose a to pose b as interpolate_poses does it (lerp + short-arc nlerp).
template <typename T>
struct Motion {
  T q0[4], q1[4], t0[3], t1[3], qb[4], tb[3];
  T sign = 1;  // -1 when q1 was flipped onto q0's hemisphere (the short arc)
  void set(const T* pa, const T* pb) {
    T na = std::sqrt(pa[3] * pa[3] + pa[4] * pa[4] + pa[5] * pa[5] + pa[6] * pa[6]);
    T nb = std::sqrt(pb[3] * pb[3] + pb[4] * pb[4] + pb[5] * pb[5] + pb[6] * pb[6]);
    T dot = 0;
    for (int a = 0; a < 4; ++a) { q0[a] = pa[3 + a] / na; q1[a] = pb[3 + a] / nb; dot += q0[a] * q1[a]; }
    sign = dot < 0 ? T(-1) : T(1);
    for (int a = 0; a < 4; ++a) { q1[a] *= sign; qb[a] = pb[3 + a]; }
    for (int a = 0; a < 3; ++a) { t0[a] = pa[a]; t1[a] = pb[a]; tb[a] = pb[a]; }
  }
  // Frame a fraction f of the way; at the last piece the end pose itself (as collide_move).
  void frame(T f, bool last, Frame<T>& fr) const {
    if (last) { fr.set(qb, tb); return; }
    T q[4], t[3];
    for (int a = 0; a < 4; ++a) q[a] = q0[a] + (q1[a] - q0[a]) * f;
    for (int a = 0; a < 3; ++a) t[a] = t0[a] + (t1[a] - t0[a]) * f;
    T nn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int a = 0; a < 4; ++a) q[a] /= nn;
    fr.set(q, t);
  }
};

template <typename T>
std::vector<Grid<T>> make_grids(const std::vector<torch::Tensor>& grids, const torch::Tensor& origins,
                                const torch::Tensor& cells) {
  const int64_t m = static_cast<int64_t>(grids.size());
  TORCH_CHECK(origins.dim() == 2 && origins.size(0) == m && origins.size(1) == 3, "origins must be (M, 3)");
  TORCH_CHECK(cells.dim() == 1 && cells.size(0) == m, "cells must be (M,)");
  auto o = origins.to(torch::kDouble).contiguous();
  auto c = cells.to(torch::kDouble).contiguous();
  const double* po = o.data_ptr<double>();
  const double* pc = c.data_ptr<double>();
  std::vector<Grid<T>> out(m);
  for (int64_t j = 0; j < m; ++j) {
    const auto& g = grids[j];
    TORCH_CHECK(g.dim() == 3 && g.is_contiguous() && g.device().is_cpu(), "SDF grids must be contiguous CPU (nx, ny, nz)");
    TORCH_CHECK(g.scalar_type() == c10::CppTypeToScalarType<T>::value, "SDF grids must have the particles' dtype");
    TORCH_CHECK(g.size(0) >= 2 && g.size(1) >= 2 && g.size(2) >= 2, "SDF grids need >= 2 nodes per axis");
    out[j].v = g.data_ptr<T>();
    for (int a = 0; a < 3; ++a) {
      out[j].n[a] = g.size(a);
      out[j].origin[a] = static_cast<T>(po[3 * j + a]);
      out[j].extent[a] = static_cast<T>(g.size(a) - 1);
    }
    out[j].cell = static_cast<T>(pc[j]);
    out[j].inv_cell = static_cast<T>(1.0 / pc[j]);
  }
  return out;
}

// Lower bound on every object's SDF at every point: (N, 3) points, (M, 7) poses -> (N, M).
torch::Tensor lower_bounds(torch::Tensor x, torch::Tensor poses, std::vector<torch::Tensor> grids,
                           torch::Tensor origins, torch::Tensor cells) {
  TORCH_CHECK(x.dim() == 2 && x.size(1) == 3 && x.device().is_cpu(), "points must be CPU (N, 3)");
  x = x.contiguous();
  poses = poses.to(x.scalar_type()).contiguous();
  const int64_t n = x.size(0), m = static_cast<int64_t>(grids.size());
  TORCH_CHECK(poses.dim() == 2 && poses.size(0) == m && poses.size(1) == 7, "poses must be (M, 7)");
  auto out = torch::empty({n, m}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "lower_bounds", [&] {
    using T = scalar_t;
    auto gs = make_grids<T>(grids, origins, cells);
    auto frames = make_frames<T>(poses);
    const T* px = x.data_ptr<T>();
    T* o = out.data_ptr<T>();
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i)
        for (int64_t j = 0; j < m; ++j) {
          T loc[3];
          frames[j].local(px + 3 * i, loc);
          o[i * m + j] = gs[j].lower_bound(loc);
        }
    });
  });
  return out;
}

// The collision plan of liquidtwin/sim/collide.py (plan_collisions), same decisions:
// object j takes part for particle i when lower_bound_ij < (reach_i + push_ij) + sweep_j +
// margin_j, push_ij the largest sweep of another object i takes part in (grown to a fixed
// point per particle); particle i moves in S_i = max over its objects j of
// max(1, ceil((reach_i + push_ij + sweep_j) / thin_j)) pieces (or `forced` when > 0), capped
// at max_pieces. Returns idx (R,), active (R, M) bool, pieces (R,), counts (S_max,)
// (counts[s-1] = rows with >= s pieces), and the uncapped largest piece count (0-d).
std::vector<torch::Tensor> plan(torch::Tensor x, torch::Tensor delta, torch::Tensor pose_a,
                                std::vector<torch::Tensor> grids, torch::Tensor origins, torch::Tensor cells,
                                torch::Tensor sweep, torch::Tensor margin, torch::Tensor thin, int64_t max_pieces,
                                int64_t forced) {
  TORCH_CHECK(x.dim() == 2 && x.size(1) == 3 && x.device().is_cpu(), "positions must be CPU (N, 3)");
  TORCH_CHECK(delta.sizes() == x.sizes(), "delta must match positions");
  TORCH_CHECK(max_pieces >= 1, "max_pieces must be >= 1");
  x = x.contiguous();
  delta = delta.to(x.scalar_type()).contiguous();
  pose_a = pose_a.to(x.scalar_type()).contiguous();
  sweep = sweep.to(x.scalar_type()).contiguous();
  margin = margin.to(x.scalar_type()).contiguous();
  thin = thin.to(torch::kDouble).contiguous();
  const int64_t n = x.size(0), m = static_cast<int64_t>(grids.size());
  TORCH_CHECK(pose_a.dim() == 2 && pose_a.size(0) == m && pose_a.size(1) == 7, "poses must be (M, 7)");
  TORCH_CHECK(sweep.numel() == m && margin.numel() == m && thin.numel() == m, "sweep, margin, thin must be (M,)");
  std::vector<uint8_t> act(n * m, 0);
  std::vector<int64_t> need(n, 0), count(n, 0);
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "collide_plan", [&] {
    using T = scalar_t;
    auto gs = make_grids<T>(grids, origins, cells);
    auto frames = make_frames<T>(pose_a);
    const T* px = x.data_ptr<T>();
    const T* pd = delta.data_ptr<T>();
    const T* sw = sweep.data_ptr<T>();
    const T* mg = margin.data_ptr<T>();
    const double* th = thin.data_ptr<double>();
    const bool grow = m > 1 && std::any_of(sw, sw + m, [](T v) { return v > 0; });
    // The most push object j can get from the others (0 when nothing grows): a lower bound at
    // or above ((reach + most) + sweep) + margin keeps j out in every round, as float sums
    // round monotonically, so its exact value is not needed.
    std::vector<T> most_push(m, T(0));
    for (int64_t j = 0; grow && j < m; ++j)
      for (int64_t k = 0; k < m; ++k) if (k != j) most_push[j] = std::max(most_push[j], sw[k]);
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      std::vector<T> start(m), push(m, T(0));
      std::vector<uint8_t> grown(m);
      for (int64_t i = b; i < e; ++i) {
        const T dx = pd[3 * i], dy = pd[3 * i + 1], dz = pd[3 * i + 2];
        const T reach = std::sqrt(dx * dx + dy * dy + dz * dz);
        uint8_t* a = act.data() + i * m;
        for (int64_t j = 0; j < m; ++j) {
          T loc[3];
          frames[j].local(px + 3 * i, loc);
          start[j] = gs[j].lower_bound_below(loc, ((reach + most_push[j]) + sw[j]) + mg[j]);
          push[j] = 0;
          a[j] = start[j] < ((reach + push[j]) + sw[j]) + mg[j];
        }
        for (int64_t round = 0; grow && round < m; ++round) {
          for (int64_t j = 0; j < m; ++j) {  // largest sweep of another object i takes part in
            T p = 0;
            for (int64_t k = 0; k < m; ++k) if (k != j && a[k]) p = std::max(p, sw[k]);
            push[j] = p;
          }
          bool same = true;
          for (int64_t j = 0; j < m; ++j) {
            grown[j] = start[j] < ((reach + push[j]) + sw[j]) + mg[j];
            same &= grown[j] == a[j];
          }
          if (same) break;
          std::copy(grown.begin(), grown.end(), a);
        }
        int64_t c = 0;  // this particle's pieces: each at most a third of every wall it can meet
        for (int64_t j = 0; j < m; ++j) {
          if (!a[j]) continue;
          const T travel = reach + push[j];
          const double s = std::ceil((static_cast<double>(travel) + static_cast<double>(sw[j])) / th[j]);
          c = std::max<int64_t>(c, std::max<int64_t>(1, static_cast<int64_t>(s)));
        }
        need[i] = c;
      }
    });
  });
  int64_t most = 0, rows = 0;
  for (int64_t i = 0; i < n; ++i) {
    int64_t c = need[i];
    if (c > 0 && forced > 0) c = forced;
    most = std::max(most, c);
    count[i] = std::min(c, max_pieces);
    rows += c > 0;
  }
  const int64_t top = std::min(most, max_pieces);
  // Stable counting sort by piece count, most first.
  std::vector<int64_t> hist(top + 2, 0);
  for (int64_t i = 0; i < n; ++i) if (count[i] > 0) ++hist[count[i]];
  auto counts_t = torch::zeros({top}, torch::kInt64);
  int64_t* counts = counts_t.data_ptr<int64_t>();
  std::vector<int64_t> pos(top + 2, 0);
  int64_t acc = 0;
  for (int64_t c = top; c >= 1; --c) { pos[c] = acc; acc += hist[c]; counts[c - 1] = acc; }
  auto idx_t = torch::empty({rows}, torch::kInt64);
  auto pieces_t = torch::empty({rows}, torch::kInt64);
  auto active_t = torch::empty({rows, m}, torch::kBool);
  int64_t* idx = idx_t.data_ptr<int64_t>();
  int64_t* pcs = pieces_t.data_ptr<int64_t>();
  bool* av = active_t.data_ptr<bool>();
  for (int64_t i = 0; i < n; ++i) {
    if (count[i] == 0) continue;
    const int64_t r = pos[count[i]]++;
    idx[r] = i;
    pcs[r] = count[i];
    for (int64_t j = 0; j < m; ++j) av[r * m + j] = act[i * m + j] != 0;
  }
  return {idx_t, active_t, pieces_t, counts_t, torch::tensor(most, torch::kInt64)};
}

// What one piece of a planned particle's move did: the position after the piece's add, the
// centre value and its nearest object, and, when it pushed (pen), the stencil's nearest
// objects and the unnormalised normal g (hi − lo per axis).
template <typename T>
struct PieceRecord {
  T p1[3], centre, g[3];
  int64_t jc, jl[3], jh[3];
  bool pen;
};

// One planned particle's anti-clipped move, shared by collide_pieces and its backward's
// replay so both follow the same path: S pieces of d, each followed by the push-out
// p += ReLU(c − SDF(p)) n̂ against the particle's active objects posed for that piece.
template <typename T>
struct Mover {
  const std::vector<Grid<T>>& gs;
  const std::vector<Motion<T>>& motion;
  const bool fixed;
  const T cd, dil;
  std::vector<Frame<T>> fr, cache;
  std::vector<int64_t> act;
  int64_t cached = -1;

  Mover(const std::vector<Grid<T>>& g, const std::vector<Motion<T>>& mo, bool fx, T c, T d)
      : gs(g), motion(mo), fixed(fx), cd(c), dil(d), fr(mo.size()) {}

  // The objects of plan row `row` (active[r], M flags).
  void activate(const uint8_t* row) {
    act.clear();
    for (int64_t j = 0; j < static_cast<int64_t>(motion.size()); ++j) if (row[j]) act.push_back(j);
  }

  // Frames of the active objects at piece k of S (the end pose throughout when fixed). Every
  // object's frames at pieces 1 … S are made once per S (plan rows come sorted by S).
  void frames(int64_t k, int64_t S) {
    const int64_t m = static_cast<int64_t>(motion.size());
    if (fixed) {
      if (cached != 0) {
        cache.resize(m);
        for (int64_t j = 0; j < m; ++j) motion[j].frame(T(1), true, cache[j]);
        cached = 0;
      }
      for (int64_t j : act) fr[j] = cache[j];
      return;
    }
    if (S != cached) {
      cache.resize((S + 1) * m);
      for (int64_t kk = 1; kk <= S; ++kk)
        for (int64_t j = 0; j < m; ++j) {
          motion[j].frame(static_cast<T>(static_cast<double>(kk) / static_cast<double>(S)), kk == S,
                          cache[kk * m + j]);
        }
      cached = S;
    }
    for (int64_t j : act) fr[j] = cache[k * m + j];
  }

  // min over the active objects of the SDF at p, the nearest object in `arg` (the first on
  // ties, as std::min; -1 and +inf with no object).
  T nearest(const T p[3], int64_t& arg) const {
    T best = std::numeric_limits<T>::infinity();
    arg = -1;
    for (int64_t j : act) {
      T loc[3];
      fr[j].local(p, loc);
      const T v = gs[j].value(loc);
      if (arg < 0 || v < best) { best = v; arg = j; }
    }
    return best;
  }

  // Moves p (3,) by S pieces of d (3,); rec: S records to fill, or nullptr.
  void run(T p[3], const T d[3], int64_t S, PieceRecord<T>* rec) {
    if (fixed) frames(S, S);
    PieceRecord<T> scratch;
    for (int64_t k = 1; k <= S; ++k) {
      PieceRecord<T>& pc = rec ? rec[k - 1] : scratch;
      for (int a = 0; a < 3; ++a) { p[a] = p[a] + d[a]; pc.p1[a] = p[a]; }
      if (!fixed) frames(k, S);
      pc.centre = nearest(p, pc.jc);
      pc.pen = pc.centre < cd;
      if (!pc.pen) continue;  // depth ReLU(c - SDF) = 0: no push
      for (int a = 0; a < 3; ++a) {
        T q[3] = {p[0], p[1], p[2]};
        q[a] = p[a] + -dil;
        const T lo = nearest(q, pc.jl[a]);
        q[a] = p[a] + dil;
        const T hi = nearest(q, pc.jh[a]);
        pc.g[a] = hi - lo;
      }
      const T len = std::max(std::sqrt(pc.g[0] * pc.g[0] + pc.g[1] * pc.g[1] + pc.g[2] * pc.g[2]),
                             static_cast<T>(1e-12));
      const T depth = cd - pc.centre;
      for (int a = 0; a < 3; ++a) p[a] = p[a] + depth * (pc.g[a] / len);
    }
  }
};

// The inputs of collide_pieces and its backward, checked and made contiguous in x's dtype.
struct PieceInputs {
  torch::Tensor x, delta, pose_a, pose_b, idx, active, pieces;
  int64_t n, m, rows;
};

inline PieceInputs piece_inputs(torch::Tensor x, torch::Tensor delta, torch::Tensor pose_a, torch::Tensor pose_b,
                                int64_t m, torch::Tensor idx, torch::Tensor active, torch::Tensor pieces) {
  TORCH_CHECK(x.dim() == 2 && x.size(1) == 3 && x.device().is_cpu(), "positions must be CPU (N, 3)");
  TORCH_CHECK(delta.sizes() == x.sizes(), "delta must match positions");
  PieceInputs in;
  in.x = x.contiguous();
  in.delta = delta.to(x.scalar_type()).contiguous();
  in.pose_a = pose_a.to(x.scalar_type()).contiguous();
  in.pose_b = pose_b.to(x.scalar_type()).contiguous();
  in.idx = idx.to(torch::kInt64).contiguous();
  in.pieces = pieces.to(torch::kInt64).contiguous();
  in.active = active.to(torch::kUInt8).contiguous();
  in.n = x.size(0);
  in.m = m;
  in.rows = in.idx.size(0);
  TORCH_CHECK(in.pose_a.dim() == 2 && in.pose_a.size(0) == m && in.pose_a.size(1) == 7 &&
              in.pose_b.sizes() == in.pose_a.sizes(), "poses must be (M, 7)");
  TORCH_CHECK(in.pieces.size(0) == in.rows && in.active.dim() == 2 && in.active.size(0) == in.rows &&
              in.active.size(1) == m, "plan tensors must be idx (R,), active (R, M), pieces (R,)");
  const int64_t* pi = in.idx.data_ptr<int64_t>();
  const int64_t* ps = in.pieces.data_ptr<int64_t>();
  for (int64_t r = 0; r < in.rows; ++r)
    TORCH_CHECK(pi[r] >= 0 && pi[r] < in.n && ps[r] >= 1, "bad collision plan (index or piece count)");
  return in;
}

// Anti-clipped move of the planned particles. Particle idx[r] moves by delta in pieces[r]
// equal pieces; after piece k it is pushed out of its active objects (active[r, j]) posed a
// fraction k / pieces[r] of the way from pose_a to pose_b (pose_b itself at the last piece,
// pose_b throughout when `fixed`). Everyone else moves by delta. Returns (N, 3) positions.
torch::Tensor collide_pieces(torch::Tensor x, torch::Tensor delta, torch::Tensor pose_a, torch::Tensor pose_b,
                             std::vector<torch::Tensor> grids, torch::Tensor origins, torch::Tensor cells,
                             torch::Tensor idx, torch::Tensor active, torch::Tensor pieces,
                             double collision_distance, double dilation, bool fixed) {
  const auto in = piece_inputs(x, delta, pose_a, pose_b, static_cast<int64_t>(grids.size()), idx, active, pieces);
  const int64_t m = in.m, rows = in.rows;
  x = in.x; delta = in.delta; pose_a = in.pose_a; pose_b = in.pose_b;
  idx = in.idx; active = in.active; pieces = in.pieces;
  auto out = x + delta;
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "collide_pieces", [&] {
    using T = scalar_t;
    auto gs = make_grids<T>(grids, origins, cells);
    std::vector<Motion<T>> motion(m);
    for (int64_t j = 0; j < m; ++j) motion[j].set(pose_a.data_ptr<T>() + 7 * j, pose_b.data_ptr<T>() + 7 * j);
    const T* px = x.data_ptr<T>();
    const T* pd = delta.data_ptr<T>();
    const int64_t* pi = idx.data_ptr<int64_t>();
    const int64_t* ps = pieces.data_ptr<int64_t>();
    const uint8_t* pa = active.data_ptr<uint8_t>();
    T* po = out.data_ptr<T>();
    const T cd = static_cast<T>(collision_distance), dil = static_cast<T>(dilation);
    at::parallel_for(0, rows, 16, [&](int64_t b, int64_t e) {
      Mover<T> mover(gs, motion, fixed, cd, dil);
      for (int64_t r = b; r < e; ++r) {
        const int64_t i = pi[r], S = ps[r];
        mover.activate(pa + r * m);
        T p[3], d[3];
        for (int a = 0; a < 3; ++a) { p[a] = px[3 * i + a]; d[a] = pd[3 * i + a] / static_cast<T>(S); }
        mover.run(p, d, S, nullptr);
        for (int a = 0; a < 3; ++a) po[3 * i + a] = p[a];
      }
    });
  });
  return out;
}


// ---------------------------------------------------------------------------------------------
// Backward of collide_pieces. Every planned particle is replayed piece by piece (the same
// arithmetic as the forward) and then reversed: the push p += ReLU(c − SDF(p)) n̂ is
// differentiated through the centre sample (its nearest object), the six stencil samples
// (each its nearest object), F.normalize, the object frames local = Rᵀ(p − t), and the
// frames' poses (nlerp between the normalised end quaternions, lerp of translations, the
// end pose itself at the last piece). Pose gradients are summed per row first and reduced in
// row order, so the result does not depend on the thread count.

// d/dq̂ of R(q̂) for a unit quaternion q̂ = (x, y, z, w), given R̄ (row-major 3×3).
template <typename T>
void quat_matrix_backward(const T q[4], const T Rb[9], T g[4]) {
  const T x = q[0], y = q[1], z = q[2], w = q[3];
  g[0] = T(2) * (y * Rb[1] + z * Rb[2] + y * Rb[3] - T(2) * x * Rb[4] - w * Rb[5] + z * Rb[6] + w * Rb[7] -
                 T(2) * x * Rb[8]);
  g[1] = T(2) * (-T(2) * y * Rb[0] + x * Rb[1] + w * Rb[2] + x * Rb[3] + z * Rb[5] - w * Rb[6] + z * Rb[7] -
                 T(2) * y * Rb[8]);
  g[2] = T(2) * (-T(2) * z * Rb[0] - w * Rb[1] + x * Rb[2] + w * Rb[3] - T(2) * z * Rb[4] + y * Rb[5] +
                 x * Rb[6] + y * Rb[7]);
  g[3] = T(2) * (-z * Rb[1] + y * Rb[2] + z * Rb[3] - x * Rb[5] - y * Rb[6] + x * Rb[7]);
}

// Adjoint of q / |q| at raw q: (ḡ − q̂ (q̂·ḡ)) / |q|, in place.
template <typename T>
void normalize_backward(const T q[4], T g[4]) {
  const T nn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  T dot = 0;
  for (int a = 0; a < 4; ++a) dot += q[a] / nn * g[a];
  for (int a = 0; a < 4; ++a) g[a] = (g[a] - q[a] / nn * dot) / nn;
}

// Per row and object: adjoints of t0, t1 (3 each), unit q0, unit (sign-flipped) q1, and the
// unit end quaternion used at last pieces (4 each).
constexpr int kPoseAcc = 18;

std::vector<torch::Tensor> collide_pieces_backward(
    torch::Tensor x, torch::Tensor delta, torch::Tensor pose_a, torch::Tensor pose_b,
    std::vector<torch::Tensor> grids, torch::Tensor origins, torch::Tensor cells, torch::Tensor idx,
    torch::Tensor active, torch::Tensor pieces, double collision_distance, double dilation, bool fixed,
    torch::Tensor grad_out) {
  TORCH_CHECK(grad_out.sizes() == x.sizes(), "the gradient must match positions");
  const auto in = piece_inputs(x, delta, pose_a, pose_b, static_cast<int64_t>(grids.size()), idx, active, pieces);
  const int64_t m = in.m, rows = in.rows;
  x = in.x; delta = in.delta; pose_a = in.pose_a; pose_b = in.pose_b;
  idx = in.idx; active = in.active; pieces = in.pieces;
  grad_out = grad_out.to(x.scalar_type()).contiguous();
  auto gx = grad_out.clone();
  auto gd = grad_out.clone();
  auto gpa = torch::zeros({m, 7}, x.options());
  auto gpb = torch::zeros({m, 7}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "collide_pieces_backward", [&] {
    using T = scalar_t;
    auto gs = make_grids<T>(grids, origins, cells);
    std::vector<Motion<T>> motion(m);
    const T* ppa = pose_a.data_ptr<T>();
    const T* ppb = pose_b.data_ptr<T>();
    for (int64_t j = 0; j < m; ++j) motion[j].set(ppa + 7 * j, ppb + 7 * j);
    const T* px = x.data_ptr<T>();
    const T* pd = delta.data_ptr<T>();
    const T* pg = grad_out.data_ptr<T>();
    const int64_t* pi = idx.data_ptr<int64_t>();
    const int64_t* ps = pieces.data_ptr<int64_t>();
    const uint8_t* pa = active.data_ptr<uint8_t>();
    T* ogx = gx.data_ptr<T>();
    T* ogd = gd.data_ptr<T>();
    const T cd = static_cast<T>(collision_distance), dil = static_cast<T>(dilation);
    std::vector<T> acc(static_cast<size_t>(rows * m * kPoseAcc), T(0));
    at::parallel_for(0, rows, 16, [&](int64_t b, int64_t e) {
      Mover<T> mover(gs, motion, fixed, cd, dil);
      const std::vector<Frame<T>>& fr = mover.fr;
      std::vector<PieceRecord<T>> rec;
      std::vector<T> Rb(m * 9), tb(m * 3);
      std::vector<uint8_t> used(m);
      // Adjoint of value w at point p of object j: p̄ += R gL w, and R̄, t̄ of object j.
      auto pull = [&](int64_t j, const T p[3], T w, T pbar[3]) {
        if (j < 0 || w == T(0)) return;
        T loc[3], gL[3];
        fr[j].local(p, loc);
        gs[j].value_grad(loc, gL);
        const T* R = fr[j].R;
        const T dd[3] = {p[0] - fr[j].t[0], p[1] - fr[j].t[1], p[2] - fr[j].t[2]};
        for (int c = 0; c < 3; ++c) {
          const T back = (R[3 * c] * gL[0] + R[3 * c + 1] * gL[1] + R[3 * c + 2] * gL[2]) * w;
          pbar[c] += back;
          tb[3 * j + c] -= back;
          for (int a = 0; a < 3; ++a) Rb[9 * j + 3 * c + a] += dd[c] * gL[a] * w;
        }
        used[j] = 1;
      };
      for (int64_t r = b; r < e; ++r) {
        const int64_t i = pi[r], S = ps[r];
        mover.activate(pa + r * m);
        T p[3], d[3];
        for (int a = 0; a < 3; ++a) { p[a] = px[3 * i + a]; d[a] = pd[3 * i + a] / static_cast<T>(S); }
        rec.resize(static_cast<size_t>(S));
        mover.run(p, d, S, rec.data());   // the forward's path, recorded
        // Reverse.
        T P[3] = {pg[3 * i], pg[3 * i + 1], pg[3 * i + 2]};
        T dbar[3] = {0, 0, 0};
        T* rowacc = acc.data() + static_cast<size_t>(r * m * kPoseAcc);
        for (int64_t k = S; k >= 1; --k) {
          const PieceRecord<T>& pc = rec[k - 1];
          const T* p1 = pc.p1;
          T pbar[3] = {P[0], P[1], P[2]};
          if (pc.pen) {
            mover.frames(k, S);
            std::fill(Rb.begin(), Rb.end(), T(0));
            std::fill(tb.begin(), tb.end(), T(0));
            std::fill(used.begin(), used.end(), 0);
            const T* g = pc.g;
            const int64_t jc = pc.jc;
            const int64_t* jl = pc.jl;
            const int64_t* jh = pc.jh;
            const T centre = pc.centre;
            T qlo[3][3], qhi[3][3];
            for (int a = 0; a < 3; ++a) {
              for (int c = 0; c < 3; ++c) { qlo[a][c] = p1[c]; qhi[a][c] = p1[c]; }
              qlo[a][a] = p1[a] + -dil;
              qhi[a][a] = p1[a] + dil;
            }
            const T raw = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
            const T len = std::max(raw, static_cast<T>(1e-12));
            const T depth = cd - centre;
            T nrm[3], nbar[3];
            T depth_bar = 0;
            for (int a = 0; a < 3; ++a) { nrm[a] = g[a] / len; depth_bar += P[a] * nrm[a]; nbar[a] = depth * P[a]; }
            T gbar[3];
            if (raw > static_cast<T>(1e-12)) {
              T dot = nrm[0] * nbar[0] + nrm[1] * nbar[1] + nrm[2] * nbar[2];
              for (int a = 0; a < 3; ++a) gbar[a] = (nbar[a] - nrm[a] * dot) / len;
            } else {
              for (int a = 0; a < 3; ++a) gbar[a] = nbar[a] / len;
            }
            pull(jc, p1, -depth_bar, pbar);
            for (int a = 0; a < 3; ++a) {
              pull(jh[a], qhi[a], gbar[a], pbar);
              pull(jl[a], qlo[a], -gbar[a], pbar);
            }
            // Frame adjoints → pose adjoints of this row.
            const bool last = fixed || k == S;
            const T f = static_cast<T>(static_cast<double>(k) / static_cast<double>(S));
            for (int64_t j : mover.act) {
              if (!used[j]) continue;
              T* A = rowacc + j * kPoseAcc;  // t0 0..2, t1 3..5, q0 6..9, q1 10..13, qend 14..17
              const Motion<T>& mo = motion[j];
              T gq[4];
              if (last) {
                T qhat[4];
                const T nn = std::sqrt(mo.qb[0] * mo.qb[0] + mo.qb[1] * mo.qb[1] + mo.qb[2] * mo.qb[2] +
                                       mo.qb[3] * mo.qb[3]);
                for (int a = 0; a < 4; ++a) qhat[a] = mo.qb[a] / nn;
                quat_matrix_backward(qhat, Rb.data() + 9 * j, gq);
                for (int a = 0; a < 4; ++a) A[14 + a] += gq[a];
                for (int a = 0; a < 3; ++a) A[3 + a] += tb[3 * j + a];
              } else {
                T qq[4], qn[4];
                for (int a = 0; a < 4; ++a) qq[a] = mo.q0[a] + (mo.q1[a] - mo.q0[a]) * f;
                const T nn = std::sqrt(qq[0] * qq[0] + qq[1] * qq[1] + qq[2] * qq[2] + qq[3] * qq[3]);
                for (int a = 0; a < 4; ++a) qn[a] = qq[a] / nn;
                quat_matrix_backward(qn, Rb.data() + 9 * j, gq);
                normalize_backward(qn, gq);   // Frame::set normalises the (unit) nlerp again
                normalize_backward(qq, gq);   // the nlerp's normalisation
                for (int a = 0; a < 4; ++a) { A[6 + a] += (T(1) - f) * gq[a]; A[10 + a] += f * gq[a]; }
                for (int a = 0; a < 3; ++a) { A[a] += (T(1) - f) * tb[3 * j + a]; A[3 + a] += f * tb[3 * j + a]; }
              }
            }
          }
          for (int a = 0; a < 3; ++a) { dbar[a] += pbar[a]; P[a] = pbar[a]; }
        }
        for (int a = 0; a < 3; ++a) { ogx[3 * i + a] = P[a]; ogd[3 * i + a] = dbar[a] / static_cast<T>(S); }
      }
    });
    // Reduce the rows in order, then through the normalisations of the end quaternions.
    T* oa = gpa.data_ptr<T>();
    T* ob = gpb.data_ptr<T>();
    for (int64_t j = 0; j < m; ++j) {
      T sum[kPoseAcc] = {};
      for (int64_t r = 0; r < rows; ++r) {
        const T* A = acc.data() + static_cast<size_t>((r * m + j) * kPoseAcc);
        for (int c = 0; c < kPoseAcc; ++c) sum[c] += A[c];
      }
      const T* qa = ppa + 7 * j + 3;
      const T* qb = ppb + 7 * j + 3;
      T g0[4], g1[4], ge[4];
      for (int a = 0; a < 4; ++a) { g0[a] = sum[6 + a]; g1[a] = sum[10 + a] * motion[j].sign; ge[a] = sum[14 + a]; }
      normalize_backward(qa, g0);
      normalize_backward(qb, g1);
      normalize_backward(qb, ge);
      for (int a = 0; a < 3; ++a) { oa[7 * j + a] = sum[a]; ob[7 * j + a] = sum[3 + a]; }
      for (int a = 0; a < 4; ++a) { oa[7 * j + 3 + a] = g0[a]; ob[7 * j + 3 + a] = g1[a] + ge[a]; }
    }
  });
  return {gx, gd, gpa, gpb};
}

// The march of segment_blocked for one segment a -> b: true when some sample lies deeper than
// tl inside an object (at most `rounds` samples; module doc of liquidtwin/sim/segments.py).
template <typename T>
bool march(const T* a, const T* b, const std::vector<Grid<T>>& gs, const std::vector<Frame<T>>& frames, T tl, T st,
           int64_t rounds) {
  const int64_t m = static_cast<int64_t>(gs.size());
  T q0[3], d[3], len2 = 0;
  for (int k = 0; k < 3; ++k) { q0[k] = a[k]; d[k] = b[k] - q0[k]; len2 += d[k] * d[k]; }
  const T len = std::sqrt(len2);
  const T inv_len = T(1) / std::max(len, T(1e-30));
  for (int k = 0; k < 3; ++k) d[k] *= inv_len;
  // Per object, what does not change along the segment (the slab test's reciprocals of its
  // direction in the object frame) and the current sample in the object frame (`loc`: the
  // box test after a step transforms the next sample, which the next round samples). Held on
  // the stack for up to kMax objects, on the heap beyond.
  struct PerObject {
    T inv[3], loc[3], ix[3], out;
    int64_t order;  // a permutation stored alongside: ob[i].order is the object at place i
  };
  constexpr int64_t kMax = 8;
  PerObject stack[kMax];
  std::vector<PerObject> heap(m > kMax ? m : 0);
  PerObject* ob = m > kMax ? heap.data() : stack;
  for (int64_t j = 0; j < m; ++j) {
    const auto& R = frames[j].R;
    for (int k = 0; k < 3; ++k) {
      const T u = d[0] * R[k] + d[1] * R[3 + k] + d[2] * R[6 + k];
      ob[j].inv[k] = T(1) / (std::abs(u) < T(1e-12) ? T(1e-12) : u);
    }
    frames[j].local(q0, ob[j].loc);
  }
  T s = 0;
  for (int64_t r = 0; r < rounds; ++r) {
    // f = min over objects of their lower bounds; an object whose grid box alone is at least
    // f away cannot lower it (its bound is >= that distance), so its 8 corners go unread.
    // Objects are taken nearest box first (`order`); the minimum does not depend on order.
    for (int64_t j = 0; j < m; ++j) {
      T du[3];
      bool in[3];
      ob[j].out = gs[j].locate(ob[j].loc, ob[j].ix, du, in);
      ob[j].order = j;
      for (int64_t i = j; i > 0 && ob[ob[i].order].out < ob[ob[i - 1].order].out; --i)
        std::swap(ob[i].order, ob[i - 1].order);
    }
    T f = std::numeric_limits<T>::infinity();
    for (int64_t i = 0; i < m; ++i) {
      const PerObject& o = ob[ob[i].order];
      if (o.out > 0 && o.out >= f) break;
      const T val = gs[ob[i].order].trilinear(o.ix);
      f = std::min(f, o.out > 0 ? std::max(o.out, val - o.out) : val);
    }
    if (f < -tl) return true;
    s += std::max(f, st);
    if (!(s < len)) return false;
    // does the rest of the segment meet any object's grid box? (every object's frame of the
    // new sample is made: the next round samples it)
    const T rest = std::max(len - s, T(0));
    T q[3];
    for (int k = 0; k < 3; ++k) q[k] = q0[k] + s * d[k];
    bool meets = false;
    for (int64_t j = 0; j < m; ++j) {
      T* p = ob[j].loc;
      frames[j].local(q, p);
      if (meets) continue;
      T enter = 0, leave = rest;
      for (int k = 0; k < 3; ++k) {
        const T lo = gs[j].origin[k], hi = lo + gs[j].extent[k] * gs[j].cell;
        const T ta = (lo - p[k]) * ob[j].inv[k], tb = (hi - p[k]) * ob[j].inv[k];
        enter = std::max(enter, std::min(ta, tb));
        leave = std::min(leave, std::max(ta, tb));
      }
      meets = enter <= leave;
    }
    if (!meets) return false;
  }
  return false;
}

// Candidate pairs of liquidtwin/sim/walls.py (facing_pairs), same rule: each particle within
// `reach` (lower bound) of an object takes its nearest object's SDF s_i (value) and outward
// normal n_i (the normalised gradient of the trilinear value, value_grad, rotated to the
// world); pair (i, k) is a candidate when x_k lies beyond i's tangent plane,
// (x_i - x_k).n_i > s_i - slack, or x_i beyond k's, (x_i - x_k).n_k < slack - s_k.
// CSR pairs row_ptr (N + 1,), col (P,) -> (P,) bool. With step > 0 a candidate stays True only
// when the march of segment_blocked (tolerance tol, smallest step `step`) from the
// lower-indexed particle to the other finds material: the pairs a wall separates
// (liquidtwin/sim/walls.py, cut_pairs).
torch::Tensor facing_pairs(torch::Tensor x, torch::Tensor row_ptr, torch::Tensor col, torch::Tensor poses,
                           std::vector<torch::Tensor> grids, torch::Tensor origins, torch::Tensor cells,
                           double slack, double reach, double tol, double step) {
  TORCH_CHECK(x.dim() == 2 && x.size(1) == 3 && x.device().is_cpu(), "points must be CPU (N, 3)");
  x = x.contiguous();
  row_ptr = row_ptr.to(torch::kLong).contiguous();
  col = col.to(torch::kLong).contiguous();
  poses = poses.to(x.scalar_type()).contiguous();
  const int64_t n = x.size(0), m = static_cast<int64_t>(grids.size());
  TORCH_CHECK(row_ptr.dim() == 1 && row_ptr.size(0) == n + 1, "row_ptr must be (N + 1,)");
  TORCH_CHECK(poses.dim() == 2 && poses.size(0) == m && poses.size(1) == 7, "poses must be (M, 7)");
  auto out = torch::zeros({col.size(0)}, x.options().dtype(torch::kBool));
  if (n == 0 || m == 0 || col.size(0) == 0) return out;
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "facing_pairs", [&] {
    using T = scalar_t;
    auto gs = make_grids<T>(grids, origins, cells);
    auto frames = make_frames<T>(poses);
    const T* px = x.data_ptr<T>();
    const int64_t* rp = row_ptr.data_ptr<int64_t>();
    const int64_t* pc = col.data_ptr<int64_t>();
    bool* o = out.data_ptr<bool>();
    std::vector<T> S(n, std::numeric_limits<T>::infinity()), N(3 * n, T(0));
    const T rc = static_cast<T>(reach), sl = static_cast<T>(slack), tl = static_cast<T>(tol), st = static_cast<T>(step);
    const int64_t rounds = step > 0 ? static_cast<int64_t>(std::ceil(reach / step)) + 2 : 0;
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) {
        T best = std::numeric_limits<T>::infinity();
        int64_t jb = -1;
        T loc[3], lb[3];
        for (int64_t j = 0; j < m; ++j) {
          frames[j].local(px + 3 * i, loc);
          const T f = gs[j].lower_bound_below(loc, best);
          if (f < best) { best = f; jb = j; for (int a = 0; a < 3; ++a) lb[a] = loc[a]; }
        }
        if (!(best < rc)) continue;
        T gl[3];
        S[i] = gs[jb].value_grad(lb, gl);
        const T nn = std::max(std::sqrt(gl[0] * gl[0] + gl[1] * gl[1] + gl[2] * gl[2]), T(1e-12));
        const T* R = frames[jb].R;
        for (int a = 0; a < 3; ++a) N[3 * i + a] = (R[3 * a] * gl[0] + R[3 * a + 1] * gl[1] + R[3 * a + 2] * gl[2]) / nn;
      }
    });
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) {
        for (int64_t q = rp[i]; q < rp[i + 1]; ++q) {
          const int64_t k = pc[q];
          if (std::isinf(S[i]) && std::isinf(S[k])) continue;
          const T d[3] = {px[3 * i] - px[3 * k], px[3 * i + 1] - px[3 * k + 1], px[3 * i + 2] - px[3 * k + 2]};
          const T di = d[0] * N[3 * i] + d[1] * N[3 * i + 1] + d[2] * N[3 * i + 2];
          const T dk = d[0] * N[3 * k] + d[1] * N[3 * k + 1] + d[2] * N[3 * k + 2];
          const bool cand = (di > S[i] - sl) || (dk < sl - S[k]);
          if (cand && step > 0) {
            const int64_t lo = std::min(i, k), hi = std::max(i, k);
            o[q] = march<T>(px + 3 * lo, px + 3 * hi, gs, frames, tl, st, rounds);
          } else {
            o[q] = cand;
          }
        }
      }
    });
  });
  return out;
}

// The CSR lists without the pairs a wall separates (facing_pairs with the march): returns
// (row_ptr, col), the inputs themselves when no pair is cut.
std::vector<torch::Tensor> cut_wall_pairs(torch::Tensor x, torch::Tensor row_ptr, torch::Tensor col,
                                          torch::Tensor poses, std::vector<torch::Tensor> grids, torch::Tensor origins,
                                          torch::Tensor cells, double slack, double reach, double tol, double step) {
  TORCH_CHECK(step > 0, "cut_wall_pairs needs a march step > 0");
  auto cut = facing_pairs(x, row_ptr, col, poses, grids, origins, cells, slack, reach, tol, step);
  const bool* c = cut.data_ptr<bool>();
  const int64_t p = cut.size(0), n = row_ptr.size(0) - 1;
  int64_t dropped = 0;
  for (int64_t q = 0; q < p; ++q) dropped += c[q];
  if (dropped == 0) return {row_ptr, col};
  auto rp = row_ptr.to(torch::kLong).contiguous();
  auto cl = col.to(torch::kLong).contiguous();
  auto new_ptr = torch::empty({n + 1}, rp.options());
  auto new_col = torch::empty({p - dropped}, cl.options());
  const int64_t* r = rp.data_ptr<int64_t>();
  const int64_t* k = cl.data_ptr<int64_t>();
  int64_t* nr = new_ptr.data_ptr<int64_t>();
  int64_t* nc = new_col.data_ptr<int64_t>();
  int64_t w = 0;
  nr[0] = 0;
  for (int64_t i = 0; i < n; ++i) {
    for (int64_t q = r[i]; q < r[i + 1]; ++q)
      if (!c[q]) nc[w++] = k[q];
    nr[i + 1] = w;
  }
  return {new_ptr, new_col};
}

// Occlusion test of liquidtwin/camera/occlusion.py (segment_blocked), same marching rule: does
// the segment start_i -> end_i pass deeper than `tol` into any object? Samples at arc lengths
// s_{k+1} = s_k + max(f(s_k), step), f the lower bound on the distance to the nearest object
// (the trilinear SDF inside a grid box; max(d_box, sdf - d_box) outside it); a ray stops when
// blocked, past its end, or when its rest meets no object's grid box (slab test).
torch::Tensor segment_blocked(torch::Tensor start, torch::Tensor end, torch::Tensor poses,
                              std::vector<torch::Tensor> grids, torch::Tensor origins, torch::Tensor cells,
                              double tol, double step) {
  TORCH_CHECK(start.dim() == 2 && start.size(1) == 3 && start.device().is_cpu(), "segment starts must be CPU (N, 3)");
  TORCH_CHECK(end.sizes() == start.sizes(), "segment ends must match the starts");
  TORCH_CHECK(step > 0 && tol >= 0, "need step > 0 and tol >= 0");
  start = start.contiguous();
  end = end.to(start.scalar_type()).contiguous();
  poses = poses.to(start.scalar_type()).contiguous();
  const int64_t n = start.size(0), m = static_cast<int64_t>(grids.size());
  TORCH_CHECK(poses.dim() == 2 && poses.size(0) == m && poses.size(1) == 7, "poses must be (M, 7)");
  auto out = torch::zeros({n}, start.options().dtype(torch::kBool));
  if (n == 0 || m == 0) return out;
  AT_DISPATCH_FLOATING_TYPES(start.scalar_type(), "segment_blocked", [&] {
    using T = scalar_t;
    auto gs = make_grids<T>(grids, origins, cells);
    auto frames = make_frames<T>(poses);
    const T* ps = start.data_ptr<T>();
    const T* pe = end.data_ptr<T>();
    bool* o = out.data_ptr<bool>();
    const T st = static_cast<T>(step), tl = static_cast<T>(tol);
    // the Python loop's round limit: ceil(longest segment / step) + 2
    double longest = 0;
    for (int64_t i = 0; i < n; ++i) {
      double l2 = 0;
      for (int a = 0; a < 3; ++a) { double d = static_cast<double>(pe[3 * i + a] - ps[3 * i + a]); l2 += d * d; }
      longest = std::max(longest, static_cast<double>(static_cast<T>(std::sqrt(l2))));
    }
    const int64_t rounds = static_cast<int64_t>(std::ceil(longest / step)) + 2;
    at::parallel_for(0, n, 64, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) o[i] = march<T>(ps + 3 * i, pe + 3 * i, gs, frames, tl, st, rounds);
    });
  });
  return out;
}

}  // namespace collide
