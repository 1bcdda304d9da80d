// Fused CPU kernels for the SPNets PBF step: neighbour search on a hash grid and the
// particle-pair passes (density/normals, pressure/tension, viscosity) with their
// hand-derived backward passes. Everything is a gather over symmetric CSR neighbour
// lists, so it parallelises over particles without atomics and is deterministic.
// The pure-torch reference lives in liquidtwin/sim/{neighbors,convsp,pbf}.py; tests check
// values and gradients against it and against finite differences (gradcheck, float64).
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include "collide_native.h"

namespace {

constexpr double kPi = 3.14159265358979323846;

template <typename T>
struct Kern {
  T h, inv_h, c_rho, c_omega, a, b;
  explicit Kern(double h_) : h(h_), inv_h(1.0 / h_) {
    c_rho = static_cast<T>(15.0 / (kPi * h_ * h_ * h_));
    c_omega = static_cast<T>(30.0 / (kPi * h_ * h_ * h_ * h_));
    const double d0 = 0.5;
    const double bb = (d0 * d0 + d0 + 1.0) / (d0 * d0);
    b = static_cast<T>(bb);
    a = static_cast<T>(1.0 - bb);
  }
  // W_rho and its derivative dW/dd.
  T rho(T d) const { T q = T(1) - d * inv_h; return c_rho * q * q; }
  T drho(T d) const { return -c_omega * (T(1) - d * inv_h); }
  // W_omega / d and its derivative.
  T g(T d) const { return c_omega * (T(1) - d * inv_h) / d; }
  T dg(T d) const { return -c_omega / (d * d); }
  // W_c / d and its derivative.
  T wc(T d) const { T x = d * inv_h; return (a * x + b) * x * x - T(1); }
  T f(T d) const { return wc(d) / d; }
  T df(T d) const {
    T x = d * inv_h;
    T dwc = (T(3) * a * x * x + T(2) * b * x) * inv_h;
    return (dwc * d - wc(d)) / (d * d);
  }
};

template <typename T>
inline T safe_dist(T r2) { return std::sqrt(std::max(r2, T(1e-30))); }

void check_csr(const torch::Tensor& x, const torch::Tensor& row_ptr, const torch::Tensor& col) {
  TORCH_CHECK(x.dim() == 2 && x.size(1) == 3, "positions must be (N, 3)");
  TORCH_CHECK(x.is_contiguous() && row_ptr.is_contiguous() && col.is_contiguous(), "inputs must be contiguous");
  TORCH_CHECK(row_ptr.scalar_type() == torch::kInt64 && col.scalar_type() == torch::kInt64, "CSR must be int64");
  TORCH_CHECK(row_ptr.numel() == x.size(0) + 1, "row_ptr must have N + 1 entries");
  TORCH_CHECK(x.device().is_cpu(), "native kernels run on the CPU");
}

// ---------------------------------------------------------------- neighbour search
// Sort points by hash-grid cell (cell = radius) and list, for every sorted point, the
// sorted indices of all other points closer than radius. Returns (order, row_ptr, col).
//
// Cells are keyed x-fastest within z, y. When the points' bounding box spans at most
// max_dense cells (default 8 n + 4096) the keys index a dense grid: a counting sort orders
// the points and one prefix sum gives every cell's range of sorted points. Otherwise each
// axis's coordinates are ranked among the occupied ones (a far-away point costs one rank, not
// a huge grid) and cells are found by binary search. Both give the same order and the same
// lists, bit for bit (tested); the dense path is the fast one for a liquid in one place.
std::vector<torch::Tensor> sorted_neighbors(torch::Tensor x, double radius, int64_t max_dense) {
  TORCH_CHECK(x.dim() == 2 && x.size(1) == 3, "positions must be (N, 3)");
  TORCH_CHECK(radius > 0, "radius must be > 0");
  x = x.contiguous().to(torch::kDouble);
  const int64_t n = x.size(0);
  const double* px = x.data_ptr<double>();
  std::vector<int64_t> c(3 * n);
  for (int64_t i = 0; i < 3 * n; ++i) c[i] = static_cast<int64_t>(std::floor(px[i] / radius));
  int64_t lo[3] = {0, 0, 0}, ext[3] = {1, 1, 1};
  for (int ax = 0; ax < 3 && n > 0; ++ax) {
    int64_t a = c[ax], b = c[ax];
    for (int64_t i = 1; i < n; ++i) { a = std::min(a, c[3 * i + ax]); b = std::max(b, c[3 * i + ax]); }
    lo[ax] = a; ext[ax] = b - a + 1;
  }
  const int64_t limit = max_dense < 0 ? 8 * n + 4096 : max_dense;
  const bool dense = static_cast<double>(ext[0]) * static_cast<double>(ext[1]) * static_cast<double>(ext[2]) <=
                     static_cast<double>(limit);

  auto order_t = torch::empty({n}, torch::kInt64);
  int64_t* order = order_t.data_ptr<int64_t>();
  std::vector<int64_t> key(n);
  std::vector<std::vector<int64_t>> uniq(3);
  std::vector<int64_t> grid_start;  // dense path: first sorted point of every grid key, + n
  if (dense) {
    const int64_t cells = ext[0] * ext[1] * ext[2];
    for (int64_t i = 0; i < n; ++i)
      key[i] = (c[3 * i] - lo[0]) + ext[0] * ((c[3 * i + 1] - lo[1]) + ext[1] * (c[3 * i + 2] - lo[2]));
    grid_start.assign(cells + 1, 0);
    for (int64_t i = 0; i < n; ++i) ++grid_start[key[i] + 1];
    for (int64_t k = 0; k < cells; ++k) grid_start[k + 1] += grid_start[k];
    std::vector<int64_t> fill(grid_start.begin(), grid_start.end() - 1);
    for (int64_t i = 0; i < n; ++i) order[fill[key[i]]++] = i;  // counting sort: stable
  } else {
    // Rank-compress each axis so keys stay small whatever the spread of the points.
    for (int ax = 0; ax < 3; ++ax) {
      auto& u = uniq[ax];
      u.resize(n);
      for (int64_t i = 0; i < n; ++i) u[i] = c[3 * i + ax];
      std::sort(u.begin(), u.end());
      u.erase(std::unique(u.begin(), u.end()), u.end());
    }
    auto rank0 = [&](int ax, int64_t v) {
      return std::lower_bound(uniq[ax].begin(), uniq[ax].end(), v) - uniq[ax].begin();
    };
    const int64_t u0 = uniq[0].size(), u1 = uniq[1].size();
    for (int64_t i = 0; i < n; ++i)
      key[i] = rank0(0, c[3 * i]) + u0 * (rank0(1, c[3 * i + 1]) + u1 * rank0(2, c[3 * i + 2]));
    std::iota(order, order + n, 0);
    std::stable_sort(order, order + n, [&](int64_t p, int64_t q) { return key[p] < key[q]; });
  }
  std::vector<double> sx(n), sy(n), sz(n);  // sorted positions, one array per axis
  std::vector<int64_t> ks(n), cs(3 * n);
  for (int64_t i = 0; i < n; ++i) {
    int64_t o = order[i];
    ks[i] = key[o];
    sx[i] = px[3 * o]; sy[i] = px[3 * o + 1]; sz[i] = px[3 * o + 2];
    for (int ax = 0; ax < 3; ++ax) cs[3 * i + ax] = c[3 * o + ax];
  }
  std::vector<int64_t> cell_key, cell_start, cell_of(n);
  for (int64_t i = 0; i < n; ++i) {
    if (i == 0 || ks[i] != ks[i - 1]) { cell_key.push_back(ks[i]); cell_start.push_back(i); }
    cell_of[i] = static_cast<int64_t>(cell_key.size()) - 1;
  }
  cell_start.push_back(n);
  // The neighbour cells of every occupied cell, looked up once per cell rather than once per
  // particle; dz, dy, dx order. The three cells of a row (dx = -1, 0, 1) have consecutive
  // keys, so each row is one contiguous range of sorted points: 9 ranges [begin, end) per
  // cell (empty when none of the row's cells is occupied).
  const int64_t nc = static_cast<int64_t>(cell_key.size());
  std::vector<int64_t> ranges(18 * nc, 0);
  if (dense) {
    at::parallel_for(0, nc, 64, [&](int64_t b, int64_t e) {
      for (int64_t ci = b; ci < e; ++ci) {
        const int64_t i = cell_start[ci];
        const int64_t gx = cs[3 * i] - lo[0], gy = cs[3 * i + 1] - lo[1], gz = cs[3 * i + 2] - lo[2];
        const int64_t x0 = std::max<int64_t>(gx - 1, 0), x1 = std::min<int64_t>(gx + 1, ext[0] - 1);
        int64_t* out = &ranges[18 * ci];
        for (int dz = -1; dz <= 1; ++dz) {
          for (int dy = -1; dy <= 1; ++dy, out += 2) {
            const int64_t y = gy + dy, z = gz + dz;
            if (y < 0 || y >= ext[1] || z < 0 || z >= ext[2]) continue;
            const int64_t row = ext[0] * (y + ext[1] * z);
            out[0] = grid_start[row + x0]; out[1] = grid_start[row + x1 + 1];
          }
        }
      }
    });
  } else {
    const int64_t u0 = uniq[0].size(), u1 = uniq[1].size();
    auto rank = [&](int ax, int64_t v) -> int64_t {  // -1 when v does not occur
      const auto& u = uniq[ax];
      auto it = std::lower_bound(u.begin(), u.end(), v);
      return (it != u.end() && *it == v) ? (it - u.begin()) : -1;
    };
    // A neighbour's rank on an axis is the cell's own ±1 when that coordinate occurs; one
    // search per row finds its occupied cells, which are consecutive.
    auto near = [&](int ax, int64_t r, int64_t cc, int d) -> int64_t {
      const auto& u = uniq[ax];
      const int64_t q = r + d;
      return (q >= 0 && q < static_cast<int64_t>(u.size()) && u[q] == cc + d) ? q : -1;
    };
    at::parallel_for(0, nc, 64, [&](int64_t b, int64_t e) {
      for (int64_t ci = b; ci < e; ++ci) {
        const int64_t i = cell_start[ci];
        const int64_t cx = cs[3 * i], cy = cs[3 * i + 1], cz = cs[3 * i + 2];
        const int64_t rx0 = rank(0, cx), ry0 = rank(1, cy), rz0 = rank(2, cz);
        const int64_t rxs[3] = {near(0, rx0, cx, -1), rx0, near(0, rx0, cx, 1)};
        int64_t* out = &ranges[18 * ci];
        for (int dz = -1; dz <= 1; ++dz) {
          const int64_t rz = near(2, rz0, cz, dz);
          for (int dy = -1; dy <= 1; ++dy, out += 2) {
            const int64_t ry = rz < 0 ? -1 : near(1, ry0, cy, dy);
            if (ry < 0) continue;
            const int64_t row = u0 * (ry + u1 * rz);
            auto it = std::lower_bound(cell_key.begin(), cell_key.end(), row + (rxs[0] >= 0 ? rxs[0] : rx0));
            int64_t lo_c = -1, hi_c = -1;
            for (int dx = 0; dx < 3; ++dx) {
              if (rxs[dx] < 0) continue;
              const int64_t k = row + rxs[dx];
              while (it != cell_key.end() && *it < k) ++it;
              if (it != cell_key.end() && *it == k) {
                const int64_t cj = it - cell_key.begin();
                if (lo_c < 0) lo_c = cj;
                hi_c = cj;
              }
            }
            if (lo_c >= 0) { out[0] = cell_start[lo_c]; out[1] = cell_start[hi_c + 1]; }
          }
        }
      }
    });
  }
  // Half the pairs are searched: point i looks only at later sorted points j > i. The rows
  // of a cell's 3×3 block come in key order (dz, dy), as do the sorted points, so rows 0–3
  // (dz = −1, and dz = 0, dy = −1) hold only earlier points, row 4 (the cell's own) both,
  // and rows 5–8 only later ones. Every pair found is then mirrored: each list is the
  // earlier neighbours (in ascending order, from the mirror) then the later ones (ascending),
  // the same list the full search gives.
  const double r2 = radius * radius;
  auto row_ptr_t = torch::zeros({n + 1}, torch::kInt64);
  int64_t* row_ptr = row_ptr_t.data_ptr<int64_t>();
  constexpr int64_t kBlock = 256;
  const int64_t nblocks = (n + kBlock - 1) / kBlock;
  std::vector<std::vector<int64_t>> found(nblocks);
  std::vector<int64_t> later(n, 0);
  at::parallel_for(0, nblocks, 1, [&](int64_t b, int64_t e) {
    for (int64_t blk = b; blk < e; ++blk) {
      auto& buf = found[blk];
      size_t k = 0;
      for (int64_t i = blk * kBlock; i < std::min(n, (blk + 1) * kBlock); ++i) {
        const int64_t* r = &ranges[18 * cell_of[i]];
        const int64_t own = std::max(r[8], i + 1);
        size_t candidates = static_cast<size_t>(std::max<int64_t>(r[9] - own, 0));
        for (int row = 5; row < 9; ++row) candidates += static_cast<size_t>(r[2 * row + 1] - r[2 * row]);
        if (buf.size() < k + candidates) buf.resize(std::max(2 * buf.size(), k + candidates));
        int64_t* out = buf.data();
        const size_t before = k;
        const double xi = sx[i], yi = sy[i], zi = sz[i];
        for (int row = 4; row < 9; ++row) {
          for (int64_t j = row == 4 ? own : r[2 * row]; j < r[2 * row + 1]; ++j) {
            const double ddx = xi - sx[j], ddy = yi - sy[j], ddz = zi - sz[j];
            out[k] = j;
            k += ddx * ddx + ddy * ddy + ddz * ddz < r2;
          }
        }
        later[i] = static_cast<int64_t>(k - before);
      }
      buf.resize(k);
    }
  });
  std::vector<int64_t> fill(n + 1, 0);  // earlier neighbours per point, then where they go
  for (const auto& buf : found)
    for (int64_t j : buf) ++fill[j];
  for (int64_t i = 0; i < n; ++i) row_ptr[i + 1] = row_ptr[i] + fill[i] + later[i];
  auto col_t = torch::empty({row_ptr[n]}, torch::kInt64);
  int64_t* col = col_t.data_ptr<int64_t>();
  for (int64_t i = 0; i < n; ++i) fill[i] = row_ptr[i];
  for (int64_t blk = 0, i = 0; blk < nblocks; ++blk) {  // i ascending: each list's earlier part ascends
    const int64_t* u = found[blk].data();
    for (; i < std::min(n, (blk + 1) * kBlock); ++i) {
      int64_t* own = col + row_ptr[i + 1] - later[i];
      for (int64_t t = 0; t < later[i]; ++t, ++u) {
        col[fill[*u]++] = i;
        own[t] = *u;
      }
    }
  }
  return {order_t, row_ptr_t, col_t};
}

// ---------------------------------------------------------------- pass A
// rho_i = sum_j W_rho(d_ij), cnt_i = #{j: d_ij < h}, n_i = sum_j (x_j - x_i)/d_ij W_c(d_ij).
std::vector<torch::Tensor> density_normals(torch::Tensor x, torch::Tensor row_ptr, torch::Tensor col, double h) {
  check_csr(x, row_ptr, col);
  const int64_t n = x.size(0);
  auto rho = torch::zeros({n}, x.options());
  auto cnt = torch::zeros({n}, x.options());
  auto nrm = torch::zeros({n, 3}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "density_normals", [&] {
    Kern<scalar_t> K(h);
    const scalar_t* p = x.data_ptr<scalar_t>();
    const int64_t* rp = row_ptr.data_ptr<int64_t>();
    const int64_t* cl = col.data_ptr<int64_t>();
    scalar_t* o_rho = rho.data_ptr<scalar_t>();
    scalar_t* o_cnt = cnt.data_ptr<scalar_t>();
    scalar_t* o_n = nrm.data_ptr<scalar_t>();
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) {
        scalar_t r = 0, c = 0, n0 = 0, n1 = 0, n2 = 0;
        for (int64_t q = rp[i]; q < rp[i + 1]; ++q) {
          int64_t j = cl[q];
          scalar_t dx = p[3 * i] - p[3 * j], dy = p[3 * i + 1] - p[3 * j + 1], dz = p[3 * i + 2] - p[3 * j + 2];
          scalar_t d = safe_dist(dx * dx + dy * dy + dz * dz);
          if (d >= K.h) continue;
          r += K.rho(d); c += 1;
          scalar_t f = K.f(d);
          n0 -= f * dx; n1 -= f * dy; n2 -= f * dz;
        }
        o_rho[i] = r; o_cnt[i] = c; o_n[3 * i] = n0; o_n[3 * i + 1] = n1; o_n[3 * i + 2] = n2;
      }
    });
  });
  return {rho, cnt, nrm};
}

torch::Tensor density_normals_backward(torch::Tensor x, torch::Tensor row_ptr, torch::Tensor col, double h,
                                       torch::Tensor g_rho, torch::Tensor g_n) {
  check_csr(x, row_ptr, col);
  g_rho = g_rho.contiguous(); g_n = g_n.contiguous();
  const int64_t n = x.size(0);
  auto gx = torch::zeros({n, 3}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "density_normals_backward", [&] {
    Kern<scalar_t> K(h);
    const scalar_t* p = x.data_ptr<scalar_t>();
    const scalar_t* gr = g_rho.data_ptr<scalar_t>();
    const scalar_t* gn = g_n.data_ptr<scalar_t>();
    const int64_t* rp = row_ptr.data_ptr<int64_t>();
    const int64_t* cl = col.data_ptr<int64_t>();
    scalar_t* o = gx.data_ptr<scalar_t>();
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t k = b; k < e; ++k) {
        scalar_t a0 = 0, a1 = 0, a2 = 0;
        for (int64_t q = rp[k]; q < rp[k + 1]; ++q) {
          int64_t j = cl[q];
          scalar_t dx = p[3 * k] - p[3 * j], dy = p[3 * k + 1] - p[3 * j + 1], dz = p[3 * k + 2] - p[3 * j + 2];
          scalar_t d = safe_dist(dx * dx + dy * dy + dz * dz);
          if (d >= K.h) continue;
          scalar_t ux = dx / d, uy = dy / d, uz = dz / d;
          scalar_t sr = K.drho(d) * (gr[k] + gr[j]);
          scalar_t m0 = gn[3 * j] - gn[3 * k], m1 = gn[3 * j + 1] - gn[3 * k + 1], m2 = gn[3 * j + 2] - gn[3 * k + 2];
          scalar_t f = K.f(d), t = K.df(d) * d * (ux * m0 + uy * m1 + uz * m2);
          a0 += sr * ux + f * m0 + t * ux;
          a1 += sr * uy + f * m1 + t * uy;
          a2 += sr * uz + f * m2 + t * uz;
        }
        o[3 * k] = a0; o[3 * k + 1] = a1; o[3 * k + 2] = a2;
      }
    });
  });
  return gx;
}

// ---------------------------------------------------------------- pass B
// P_i = sum_j (omega_i + omega_j) W_omega(d) (x_i - x_j)/d, T_i = sum_{j: d<h} (n_j - n_i).
std::vector<torch::Tensor> pressure_tension(torch::Tensor x, torch::Tensor row_ptr, torch::Tensor col, double h,
                                            torch::Tensor omega, torch::Tensor nrm) {
  check_csr(x, row_ptr, col);
  omega = omega.contiguous(); nrm = nrm.contiguous();
  const int64_t n = x.size(0);
  auto P = torch::zeros({n, 3}, x.options());
  auto T = torch::zeros({n, 3}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "pressure_tension", [&] {
    Kern<scalar_t> K(h);
    const scalar_t* p = x.data_ptr<scalar_t>();
    const scalar_t* w = omega.data_ptr<scalar_t>();
    const scalar_t* nn = nrm.data_ptr<scalar_t>();
    const int64_t* rp = row_ptr.data_ptr<int64_t>();
    const int64_t* cl = col.data_ptr<int64_t>();
    scalar_t* oP = P.data_ptr<scalar_t>();
    scalar_t* oT = T.data_ptr<scalar_t>();
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) {
        scalar_t p0 = 0, p1 = 0, p2 = 0, t0 = 0, t1 = 0, t2 = 0;
        for (int64_t q = rp[i]; q < rp[i + 1]; ++q) {
          int64_t j = cl[q];
          scalar_t dx = p[3 * i] - p[3 * j], dy = p[3 * i + 1] - p[3 * j + 1], dz = p[3 * i + 2] - p[3 * j + 2];
          scalar_t d = safe_dist(dx * dx + dy * dy + dz * dz);
          if (d >= K.h) continue;
          scalar_t s = (w[i] + w[j]) * K.g(d);
          p0 += s * dx; p1 += s * dy; p2 += s * dz;
          t0 += nn[3 * j] - nn[3 * i]; t1 += nn[3 * j + 1] - nn[3 * i + 1]; t2 += nn[3 * j + 2] - nn[3 * i + 2];
        }
        oP[3 * i] = p0; oP[3 * i + 1] = p1; oP[3 * i + 2] = p2;
        oT[3 * i] = t0; oT[3 * i + 1] = t1; oT[3 * i + 2] = t2;
      }
    });
  });
  return {P, T};
}

std::vector<torch::Tensor> pressure_tension_backward(torch::Tensor x, torch::Tensor row_ptr, torch::Tensor col, double h,
                                                     torch::Tensor omega, torch::Tensor g_P, torch::Tensor g_T) {
  check_csr(x, row_ptr, col);
  omega = omega.contiguous(); g_P = g_P.contiguous(); g_T = g_T.contiguous();
  const int64_t n = x.size(0);
  auto gx = torch::zeros({n, 3}, x.options());
  auto gw = torch::zeros({n}, x.options());
  auto gn = torch::zeros({n, 3}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "pressure_tension_backward", [&] {
    Kern<scalar_t> K(h);
    const scalar_t* p = x.data_ptr<scalar_t>();
    const scalar_t* w = omega.data_ptr<scalar_t>();
    const scalar_t* gP = g_P.data_ptr<scalar_t>();
    const scalar_t* gT = g_T.data_ptr<scalar_t>();
    const int64_t* rp = row_ptr.data_ptr<int64_t>();
    const int64_t* cl = col.data_ptr<int64_t>();
    scalar_t* ox = gx.data_ptr<scalar_t>();
    scalar_t* ow = gw.data_ptr<scalar_t>();
    scalar_t* on = gn.data_ptr<scalar_t>();
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t k = b; k < e; ++k) {
        scalar_t a0 = 0, a1 = 0, a2 = 0, aw = 0, n0 = 0, n1 = 0, n2 = 0;
        for (int64_t q = rp[k]; q < rp[k + 1]; ++q) {
          int64_t j = cl[q];
          scalar_t dx = p[3 * k] - p[3 * j], dy = p[3 * k + 1] - p[3 * j + 1], dz = p[3 * k + 2] - p[3 * j + 2];
          scalar_t d = safe_dist(dx * dx + dy * dy + dz * dz);
          if (d >= K.h) continue;
          scalar_t m0 = gP[3 * k] - gP[3 * j], m1 = gP[3 * k + 1] - gP[3 * j + 1], m2 = gP[3 * k + 2] - gP[3 * j + 2];
          scalar_t g = K.g(d), dot = dx * m0 + dy * m1 + dz * m2;
          aw += g * dot;
          scalar_t sw = w[k] + w[j], t = K.dg(d) * dot / d;
          a0 += sw * (g * m0 + t * dx);
          a1 += sw * (g * m1 + t * dy);
          a2 += sw * (g * m2 + t * dz);
          n0 += gT[3 * j] - gT[3 * k]; n1 += gT[3 * j + 1] - gT[3 * k + 1]; n2 += gT[3 * j + 2] - gT[3 * k + 2];
        }
        ox[3 * k] = a0; ox[3 * k + 1] = a1; ox[3 * k + 2] = a2; ow[k] = aw;
        on[3 * k] = n0; on[3 * k + 1] = n1; on[3 * k + 2] = n2;
      }
    });
  });
  return {gx, gw, gn};
}

// ---------------------------------------------------------------- viscosity pass
// U_i = sum_j W_rho(d_ij) (v_j - v_i).
torch::Tensor viscosity(torch::Tensor x, torch::Tensor row_ptr, torch::Tensor col, double h, torch::Tensor v) {
  check_csr(x, row_ptr, col);
  v = v.contiguous();
  const int64_t n = x.size(0);
  auto U = torch::zeros({n, 3}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "viscosity", [&] {
    Kern<scalar_t> K(h);
    const scalar_t* p = x.data_ptr<scalar_t>();
    const scalar_t* pv = v.data_ptr<scalar_t>();
    const int64_t* rp = row_ptr.data_ptr<int64_t>();
    const int64_t* cl = col.data_ptr<int64_t>();
    scalar_t* o = U.data_ptr<scalar_t>();
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) {
        scalar_t u0 = 0, u1 = 0, u2 = 0;
        for (int64_t q = rp[i]; q < rp[i + 1]; ++q) {
          int64_t j = cl[q];
          scalar_t dx = p[3 * i] - p[3 * j], dy = p[3 * i + 1] - p[3 * j + 1], dz = p[3 * i + 2] - p[3 * j + 2];
          scalar_t d = safe_dist(dx * dx + dy * dy + dz * dz);
          if (d >= K.h) continue;
          scalar_t wr = K.rho(d);
          u0 += wr * (pv[3 * j] - pv[3 * i]); u1 += wr * (pv[3 * j + 1] - pv[3 * i + 1]); u2 += wr * (pv[3 * j + 2] - pv[3 * i + 2]);
        }
        o[3 * i] = u0; o[3 * i + 1] = u1; o[3 * i + 2] = u2;
      }
    });
  });
  return U;
}

std::vector<torch::Tensor> viscosity_backward(torch::Tensor x, torch::Tensor row_ptr, torch::Tensor col, double h,
                                              torch::Tensor v, torch::Tensor g_U) {
  check_csr(x, row_ptr, col);
  v = v.contiguous(); g_U = g_U.contiguous();
  const int64_t n = x.size(0);
  auto gx = torch::zeros({n, 3}, x.options());
  auto gv = torch::zeros({n, 3}, x.options());
  AT_DISPATCH_FLOATING_TYPES(x.scalar_type(), "viscosity_backward", [&] {
    Kern<scalar_t> K(h);
    const scalar_t* p = x.data_ptr<scalar_t>();
    const scalar_t* pv = v.data_ptr<scalar_t>();
    const scalar_t* gu = g_U.data_ptr<scalar_t>();
    const int64_t* rp = row_ptr.data_ptr<int64_t>();
    const int64_t* cl = col.data_ptr<int64_t>();
    scalar_t* ox = gx.data_ptr<scalar_t>();
    scalar_t* ov = gv.data_ptr<scalar_t>();
    at::parallel_for(0, n, 256, [&](int64_t b, int64_t e) {
      for (int64_t k = b; k < e; ++k) {
        scalar_t a0 = 0, a1 = 0, a2 = 0, b0 = 0, b1 = 0, b2 = 0;
        for (int64_t q = rp[k]; q < rp[k + 1]; ++q) {
          int64_t j = cl[q];
          scalar_t dx = p[3 * k] - p[3 * j], dy = p[3 * k + 1] - p[3 * j + 1], dz = p[3 * k + 2] - p[3 * j + 2];
          scalar_t d = safe_dist(dx * dx + dy * dy + dz * dz);
          if (d >= K.h) continue;
          scalar_t wr = K.rho(d);
          scalar_t m0 = gu[3 * j] - gu[3 * k], m1 = gu[3 * j + 1] - gu[3 * k + 1], m2 = gu[3 * j + 2] - gu[3 * k + 2];
          b0 += wr * m0; b1 += wr * m1; b2 += wr * m2;
          scalar_t s = -K.drho(d) / d *
                       (m0 * (pv[3 * j] - pv[3 * k]) + m1 * (pv[3 * j + 1] - pv[3 * k + 1]) + m2 * (pv[3 * j + 2] - pv[3 * k + 2]));
          a0 += s * dx; a1 += s * dy; a2 += s * dz;
        }
        ox[3 * k] = a0; ox[3 * k + 1] = a1; ox[3 * k + 2] = a2;
        ov[3 * k] = b0; ov[3 * k + 1] = b1; ov[3 * k + 2] = b2;
      }
    });
  });
  return {gx, gv};
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.doc() = "liquidtwin fused CPU kernels for the SPNets PBF step";
  m.def("sorted_neighbors", &sorted_neighbors, "cell-sort points and list neighbours (order, row_ptr, col)",
        py::arg("x"), py::arg("radius"), py::arg("max_dense") = -1);
  m.def("density_normals", &density_normals);
  m.def("density_normals_backward", &density_normals_backward);
  m.def("pressure_tension", &pressure_tension);
  m.def("pressure_tension_backward", &pressure_tension_backward);
  m.def("viscosity", &viscosity);
  m.def("viscosity_backward", &viscosity_backward);
  m.def("sdf_lower_bounds", &collide::lower_bounds, "lower bounds on every object's SDF at points (N, M)");
  m.def("facing_pairs", &collide::facing_pairs,
        "neighbour pairs one of which lies beyond the other's wall plane (and, with step > 0, that a wall separates)");
  m.def("cut_wall_pairs", &collide::cut_wall_pairs, "neighbour lists without the pairs a wall separates");
  m.def("segment_blocked", &collide::segment_blocked, "occlusion: does each segment pass through an object");
  m.def("collide_plan", &collide::plan, "which particles collide with which objects, in how many pieces");
  m.def("collide_pieces", &collide::collide_pieces, "anti-clipped particle moves with SDF push-out");
  m.def("collide_pieces_backward", &collide::collide_pieces_backward,
        "gradients of collide_pieces w.r.t. positions, moves and both poses");
}
