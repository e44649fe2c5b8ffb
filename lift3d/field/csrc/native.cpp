// CPU kernels of lift3d's grid field (built on first use by lift3d/field/native.py).
//
// Each kernel does in one pass over the points what the pure-torch path (lift3d/field/grids.py,
// lift3d/field/encodings.py) does with a dozen elementwise operators and their temporaries: the 8 corner
// indices and trilinear weights of every level, the gather, the weighted sum, the positional encoding,
// the spherical harmonics. The tests compare every kernel with the torch path (tests/test_native.py).
//
// Layouts follow the torch path exactly: grid tables are [R^3, C] channels-last with node index
// x + R (y + R z); node i sits at i / (R - 1); points are clamped to [0, 1].

#include <ATen/Parallel.h>
#include <ATen/core/Tensor.h>
#include <torch/library.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace {

constexpr int64_t kGrain = 2048;  // points per parallel task

struct Corners {
  int64_t idx[8];
  float w[8];
};

// Same arithmetic (float32, same order) as trilinear_corners in grids.py.
inline void corners_of(const float* u, int64_t r, Corners& c) {
  float f[3];
  int64_t i0[3];
  const float top = static_cast<float>(r - 2);
  for (int d = 0; d < 3; ++d) {
    float v = u[d];
    v = v < 0.f ? 0.f : (v > 1.f ? 1.f : v);
    const float p = v * static_cast<float>(r - 1);
    float fl = std::floor(p);
    fl = fl < 0.f ? 0.f : (fl > top ? top : fl);
    i0[d] = static_cast<int64_t>(fl);
    f[d] = p - fl;
  }
  const int64_t base = i0[0] + r * (i0[1] + r * i0[2]);
  const int64_t rr = r * r;
  const int64_t offs[8] = {0, 1, r, r + 1, rr, rr + 1, rr + r, rr + r + 1};
  const float gx = 1.f - f[0], gy = 1.f - f[1], gz = 1.f - f[2];
  const float fx = f[0], fy = f[1], fz = f[2];
  c.w[0] = gx * gy * gz;
  c.w[1] = fx * gy * gz;
  c.w[2] = gx * fy * gz;
  c.w[3] = fx * fy * gz;
  c.w[4] = gx * gy * fz;
  c.w[5] = fx * gy * fz;
  c.w[6] = gx * fy * fz;
  c.w[7] = fx * fy * fz;
  for (int k = 0; k < 8; ++k) c.idx[k] = base + offs[k];
}

template <int C>
inline void lerp_row(const float* table, const Corners& c, float* out, int64_t channels) {
  const int64_t ch = C > 0 ? C : channels;
  for (int64_t j = 0; j < ch; ++j) out[j] = 0.f;
  for (int k = 0; k < 8; ++k) {
    const float* row = table + c.idx[k] * ch;
    const float w = c.w[k];
    for (int64_t j = 0; j < ch; ++j) out[j] += w * row[j];
  }
}

// One level's trilinear features of one point (the channel counts in use get unrolled loops).
inline void lerp_level(const float* table, const Corners& c, float* out, int64_t channels) {
  switch (channels) {
    case 1: lerp_row<1>(table, c, out, 1); break;
    case 2: lerp_row<2>(table, c, out, 2); break;
    case 4: lerp_row<4>(table, c, out, 4); break;
    case 8: lerp_row<8>(table, c, out, 8); break;
    default: lerp_row<0>(table, c, out, channels);
  }
}

void check_points(const at::Tensor& u, const char* name) {
  TORCH_CHECK(u.device().is_cpu() && u.scalar_type() == at::kFloat && u.dim() == 2 && u.size(1) == 3 &&
                  u.is_contiguous(),
              name, ": expected a contiguous float32 CPU tensor [N, 3]");
}

void check_out(const at::Tensor& out, int64_t n, int64_t last_col) {
  TORCH_CHECK(out.device().is_cpu() && out.scalar_type() == at::kFloat && out.dim() == 2 &&
                  out.size(0) == n && out.size(1) >= last_col && out.stride(1) == 1,
              "out: expected a float32 CPU tensor [N, >= ", last_col, "] with unit column stride");
}

}  // namespace

// Trilinear features of every level of a dense grid, written to out[:, col : col + levels * C].
void grid_forward(const at::Tensor& u, const std::vector<at::Tensor>& tables,
                  const std::vector<int64_t>& resolutions, at::Tensor out, int64_t col) {
  check_points(u, "grid_forward");
  TORCH_CHECK(tables.size() == resolutions.size(), "grid_forward: one resolution per table");
  const int64_t n = u.size(0);
  if (tables.empty() || n == 0) return;
  const int64_t channels = tables[0].size(1);
  check_out(out, n, col + static_cast<int64_t>(tables.size()) * channels);
  std::vector<const float*> tptr;
  for (size_t l = 0; l < tables.size(); ++l) {
    const auto& t = tables[l];
    TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == at::kFloat && t.is_contiguous() &&
                    t.size(1) == channels && t.size(0) == resolutions[l] * resolutions[l] * resolutions[l],
                "grid_forward: table ", l, " must be a contiguous float32 [R^3, C]");
    tptr.push_back(t.data_ptr<float>());
  }
  const float* up = u.data_ptr<float>();
  float* op = out.data_ptr<float>();
  const int64_t ld = out.stride(0);
  at::parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    Corners c, ahead;
    for (int64_t i = begin; i < end; ++i) {
      float* row = op + i * ld + col;
      for (size_t l = 0; l < tptr.size(); ++l) {
        // Fetch the corner rows of a point a few ahead: the fine levels do not fit in the cache, and the
        // independent loads overlap instead of waiting one after the other.
        if (i + 8 < end) {
          corners_of(up + 3 * (i + 8), resolutions[l], ahead);
          for (int k = 0; k < 8; k += 2) __builtin_prefetch(tptr[l] + ahead.idx[k] * channels);
        }
        corners_of(up + 3 * i, resolutions[l], c);
        lerp_level(tptr[l], c, row + static_cast<int64_t>(l) * channels, channels);
      }
    }
  });
}

// Gradient of grid_forward: grads[l][idx] += w * grad_out[:, col + l * C : ...], in place.
//
// Deterministic and free of atomics: every thread owns a contiguous range of table rows and scans all
// points, adding only the corners that fall in its range (computing the corners twice is cheap next to
// the scattered writes).
void grid_backward(const at::Tensor& u, const at::Tensor& grad_out, int64_t col,
                   std::vector<at::Tensor> grads, const std::vector<int64_t>& resolutions) {
  check_points(u, "grid_backward");
  TORCH_CHECK(grads.size() == resolutions.size(), "grid_backward: one resolution per gradient");
  const int64_t n = u.size(0);
  if (grads.empty() || n == 0) return;
  const int64_t channels = grads[0].size(1);
  TORCH_CHECK(grad_out.scalar_type() == at::kFloat && grad_out.dim() == 2 && grad_out.size(0) == n &&
                  grad_out.stride(1) == 1 && grad_out.size(1) >= col + static_cast<int64_t>(grads.size()) * channels,
              "grid_backward: grad_out must be float32 [N, >= col + levels * C] with unit column stride");
  for (size_t l = 0; l < grads.size(); ++l) {
    const auto& g = grads[l];
    TORCH_CHECK(g.device().is_cpu() && g.scalar_type() == at::kFloat && g.is_contiguous() &&
                    g.size(1) == channels && g.size(0) == resolutions[l] * resolutions[l] * resolutions[l],
                "grid_backward: gradient ", l, " must be a contiguous float32 [R^3, C]");
  }
  const float* up = u.data_ptr<float>();
  const float* gp = grad_out.data_ptr<float>();
  const int64_t ld = grad_out.stride(0);
  const int64_t parts = std::max<int64_t>(1, at::get_num_threads());
  at::parallel_for(0, parts, 1, [&](int64_t pbegin, int64_t pend) {
    Corners c;
    for (size_t l = 0; l < grads.size(); ++l) {
      const int64_t rows = grads[l].size(0);
      const int64_t lo = rows * pbegin / parts, hi = rows * pend / parts;
      float* gt = grads[l].data_ptr<float>();
      const int64_t r = resolutions[l];
      for (int64_t i = 0; i < n; ++i) {
        corners_of(up + 3 * i, r, c);
        // Corners span base .. base + r^2 + r + 1: skip points far outside this thread's rows at once.
        if (c.idx[7] < lo || c.idx[0] >= hi) continue;
        const float* src = gp + i * ld + col + static_cast<int64_t>(l) * channels;
        for (int k = 0; k < 8; ++k) {
          const int64_t idx = c.idx[k];
          if (idx < lo || idx >= hi) continue;
          float* dst = gt + idx * channels;
          const float w = c.w[k];
          for (int64_t j = 0; j < channels; ++j) dst[j] += w * src[j];
        }
      }
    }
  });
}

// sin(pi x), cos(pi x) for |x| <= 1 in double: Taylor series of the half angle (|t| <= pi/2, remainder
// below 1e-9), then the double-angle formulas. A few multiplications instead of two libm calls.
inline void sincos_pi(float xf, double& s, double& c) {
  const double t = 0.5 * M_PI * static_cast<double>(xf), t2 = t * t;
  const double sh = t * (1.0 + t2 * (-1.0 / 6 + t2 * (1.0 / 120 + t2 * (-1.0 / 5040 + t2 * (1.0 / 362880 +
                    t2 * (-1.0 / 39916800 + t2 * (1.0 / 6227020800.0)))))));
  const double ch = 1.0 + t2 * (-0.5 + t2 * (1.0 / 24 + t2 * (-1.0 / 720 + t2 * (1.0 / 40320 + t2 * (-1.0 / 3628800 +
                    t2 * (1.0 / 479001600.0 + t2 * (-1.0 / 87178291200.0)))))));
  s = 2.0 * sh * ch;
  c = (ch - sh) * (ch + sh);
}

// NeRF positional encoding of one point's x = 2u - 1 into row[0 : 3 (1 + 2 frequencies)]: [x, sin(2^k pi x),
// cos(2^k pi x)] (k < frequencies, x/y/z fastest), the layout of lift3d.field.encodings.positional_encoding.
inline void positional_row(const float* u, int64_t frequencies, float* row) {
  float x[3];
  for (int d = 0; d < 3; ++d) x[d] = u[d] * 2.f - 1.f;
  for (int d = 0; d < 3; ++d) row[d] = x[d];
  float* s = row + 3;
  float* co = row + 3 + 3 * frequencies;
  // sin and cos of pi x once (in double), then the double-angle formulas for 2^k pi x: a libm call per
  // value cost more than the decoders here. The error doubles per octave; in double it stays below
  // float rounding for the handful of frequencies used.
  for (int d = 0; d < 3; ++d) {
    double sv, cv;
    sincos_pi(x[d], sv, cv);
    for (int64_t k = 0; k < frequencies; ++k) {
      s[3 * k + d] = static_cast<float>(sv);
      co[3 * k + d] = static_cast<float>(cv);
      const double s2 = 2.0 * sv * cv, c2 = (cv - sv) * (cv + sv);
      sv = s2;
      cv = c2;
    }
  }
}

// NeRF positional encoding of x = 2u - 1, [x, sin(2^k pi x), cos(2^k pi x)] (k < frequencies, x/y/z
// fastest), written to out[:, col : col + 3 (1 + 2 frequencies)]; the layout of
// lift3d.field.encodings.positional_encoding.
void positional_forward(const at::Tensor& u, int64_t frequencies, at::Tensor out, int64_t col) {
  check_points(u, "positional_forward");
  const int64_t n = u.size(0);
  check_out(out, n, col + 3 * (1 + 2 * frequencies));
  const float* up = u.data_ptr<float>();
  float* op = out.data_ptr<float>();
  const int64_t ld = out.stride(0);
  at::parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) positional_row(up + 3 * i, frequencies, op + i * ld + col);
  });
}

// Real spherical harmonics of one unit direction up to `degree` (0-3) into r[0 : (degree + 1)^2].
inline void sh_row(const float* d, int64_t degree, float* r) {
  const float C0 = 0.28209479177387814f, C1 = 0.4886025119029199f;
  const float C2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f, -1.0925484305920792f,
                       0.5462742152960396f};
  const float C3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f, 0.3731763325901154f,
                       -0.4570457994644658f, 1.445305721320277f, -0.5900435899266435f};
  const float x = d[0], y = d[1], z = d[2];
  r[0] = C0;
  if (degree >= 1) {
    r[1] = -C1 * y;
    r[2] = C1 * z;
    r[3] = -C1 * x;
  }
  if (degree >= 2) {
    const float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
    r[4] = C2[0] * xy;
    r[5] = C2[1] * yz;
    r[6] = C2[2] * (2.f * zz - xx - yy);
    r[7] = C2[3] * xz;
    r[8] = C2[4] * (xx - yy);
    if (degree >= 3) {
      r[9] = C3[0] * y * (3.f * xx - yy);
      r[10] = C3[1] * xy * z;
      r[11] = C3[2] * y * (4.f * zz - xx - yy);
      r[12] = C3[3] * z * (2.f * zz - 3.f * xx - 3.f * yy);
      r[13] = C3[4] * x * (4.f * zz - xx - yy);
      r[14] = C3[5] * z * (xx - yy);
      r[15] = C3[6] * x * (xx - 3.f * yy);
    }
  }
}

// Real spherical harmonics of unit directions up to `degree` (0-3), written to
// out[:, col : col + (degree + 1)^2]; the basis and order of lift3d.field.encodings.spherical_harmonics.
void sh_forward(const at::Tensor& dirs, int64_t degree, at::Tensor out, int64_t col) {
  check_points(dirs, "sh_forward");
  TORCH_CHECK(degree >= 0 && degree <= 3, "sh_forward: degree must be 0..3");
  const int64_t n = dirs.size(0);
  check_out(out, n, col + (degree + 1) * (degree + 1));
  const float* dp = dirs.data_ptr<float>();
  float* op = out.data_ptr<float>();
  const int64_t ld = out.stride(0);
  at::parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) sh_row(dp + 3 * i, degree, op + i * ld + col);
  });
}

// Total variation (L_tv) on sampled node pairs of every level of a dense grid: for level l and axis a, the
// mean over k of || t_l[b + s_a] - t_l[b] ||_2 (sqrt of the squared sum + 1e-12), b = bases[l][a][k] and
// s_a = 1, R, R^2 (lift3d.field.grids.DenseGrid.total_variation). A few thousand pairs per level: one
// thread, no parallel region to wake up.

struct TvLevel {
  const float* t;
  const int64_t* base;  // [3][n]
  int64_t n, r, c;
};

// The pairs are random rows of tables larger than the cache: fetch those of pair k ahead of time.
constexpr int64_t kTvAhead = 16;
inline void tv_prefetch(const TvLevel& L, int a, int64_t k, int64_t stride) {
  if (k >= L.n) return;
  const float* p = L.t + L.base[a * L.n + k] * L.c;
  __builtin_prefetch(p);
  __builtin_prefetch(p + stride * L.c);
}

std::vector<TvLevel> tv_levels(const std::vector<at::Tensor>& tables, const std::vector<at::Tensor>& bases,
                               const std::vector<int64_t>& resolutions) {
  TORCH_CHECK(tables.size() == bases.size() && tables.size() == resolutions.size(),
              "total_variation: one base-index tensor and one resolution per table");
  std::vector<TvLevel> levels;
  for (size_t l = 0; l < tables.size(); ++l) {
    const auto& t = tables[l];
    const auto& b = bases[l];
    const int64_t r = resolutions[l];
    TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == at::kFloat && t.is_contiguous() && t.dim() == 2 &&
                    t.size(0) == r * r * r,
                "total_variation: table ", l, " must be a contiguous float32 [R^3, C]");
    TORCH_CHECK(b.scalar_type() == at::kLong && b.is_contiguous() && b.dim() == 2 && b.size(0) == 3,
                "total_variation: base indices ", l, " must be a contiguous int64 [3, n]");
    const int64_t* bp = b.data_ptr<int64_t>();
    const int64_t strides[3] = {1, r, r * r};
    for (int a = 0; a < 3; ++a)
      for (int64_t k = 0; k < b.size(1); ++k)
        TORCH_CHECK(bp[a * b.size(1) + k] >= 0 && bp[a * b.size(1) + k] + strides[a] < r * r * r,
                    "total_variation: a node pair outside table ", l);
    levels.push_back({t.data_ptr<float>(), bp, b.size(1), r, t.size(1)});
  }
  return levels;
}

void tv_forward(const std::vector<at::Tensor>& tables, const std::vector<at::Tensor>& bases,
                const std::vector<int64_t>& resolutions, at::Tensor means) {
  const std::vector<TvLevel> levels = tv_levels(tables, bases, resolutions);
  TORCH_CHECK(means.scalar_type() == at::kFloat && means.is_contiguous() &&
                  means.numel() == 3 * static_cast<int64_t>(levels.size()),
              "tv_forward: means must be a contiguous float32 [levels * 3]");
  float* mp = means.data_ptr<float>();
  for (size_t l = 0; l < levels.size(); ++l) {
    const TvLevel& L = levels[l];
    const int64_t strides[3] = {1, L.r, L.r * L.r};
    for (int a = 0; a < 3; ++a) {
      double sum = 0.0;
      for (int64_t k = 0; k < L.n; ++k) {
        tv_prefetch(L, a, k + kTvAhead, strides[a]);
        const float* p = L.t + L.base[a * L.n + k] * L.c;
        const float* q = p + strides[a] * L.c;
        float sq = 0.f;
        for (int64_t j = 0; j < L.c; ++j) sq += (q[j] - p[j]) * (q[j] - p[j]);
        sum += std::sqrt(sq + 1e-12f);
      }
      mp[l * 3 + a] = L.n ? static_cast<float>(sum / static_cast<double>(L.n)) : 0.f;
    }
  }
}

// Gradient of tv_forward's means (upstream grad_means [levels * 3]), added into grads in place.
void tv_backward(const std::vector<at::Tensor>& tables, const std::vector<at::Tensor>& bases,
                 const std::vector<int64_t>& resolutions, const at::Tensor& grad_means, std::vector<at::Tensor> grads) {
  const std::vector<TvLevel> levels = tv_levels(tables, bases, resolutions);
  TORCH_CHECK(grad_means.scalar_type() == at::kFloat && grad_means.is_contiguous() &&
                  grad_means.numel() == 3 * static_cast<int64_t>(levels.size()) && grads.size() == levels.size(),
              "tv_backward: grad_means [levels * 3] and one gradient per table");
  const float* gm = grad_means.data_ptr<float>();
  for (size_t l = 0; l < levels.size(); ++l) {
    const TvLevel& L = levels[l];
    TORCH_CHECK(grads[l].scalar_type() == at::kFloat && grads[l].is_contiguous() && grads[l].sizes() == tables[l].sizes(),
                "tv_backward: gradient ", l, " must be a contiguous float32 of its table's shape");
    float* g = grads[l].data_ptr<float>();
    const int64_t strides[3] = {1, L.r, L.r * L.r};
    for (int a = 0; a < 3; ++a) {
      if (L.n == 0) continue;
      const float scale = gm[l * 3 + a] / static_cast<float>(L.n);
      for (int64_t k = 0; k < L.n; ++k) {
        tv_prefetch(L, a, k + kTvAhead, strides[a]);
        if (k + kTvAhead < L.n) {  // and the gradient rows it will add to
          const float* gp = g + L.base[a * L.n + k + kTvAhead] * L.c;
          __builtin_prefetch(gp, 1);
          __builtin_prefetch(gp + strides[a] * L.c, 1);
        }
        const int64_t b = L.base[a * L.n + k];
        const float* p = L.t + b * L.c;
        const float* q = p + strides[a] * L.c;
        float sq = 0.f;
        for (int64_t j = 0; j < L.c; ++j) sq += (q[j] - p[j]) * (q[j] - p[j]);
        const float coef = scale / std::sqrt(sq + 1e-12f);
        float* gp = g + b * L.c;
        float* gq = gp + strides[a] * L.c;
        for (int64_t j = 0; j < L.c; ++j) {
          const float d = coef * (q[j] - p[j]);
          gq[j] += d;
          gp[j] -= d;
        }
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------------
// Scene space: normalised points -> grid coordinates u in [0, 1]^3 and whether the field may have density
// there (inside a bounded scene, in a cell a training camera observes, in a cell the occupancy grid marks
// occupied). lift3d.field.space.SceneSpace.forward and lift3d.field.encodings.contract in one pass.

enum Contraction : int64_t { kNone = 0, kLinf = 1, kL2 = 2 };

struct Space {
  int64_t contraction;
  float extent;
  const bool* observed;  // [Ro^3] or null
  int64_t ro;
  const bool* occupied;  // [Rc^3] or null
  int64_t rc;

  // Returns valid; writes u.
  inline bool map(const float* x, float* u) const {
    float c[3] = {x[0], x[1], x[2]};
    if (contraction != kNone) {
      float n;
      if (contraction == kLinf) {
        n = std::max(std::fabs(c[0]), std::max(std::fabs(c[1]), std::fabs(c[2])));
      } else {
        n = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
      }
      n = std::max(n, 1e-12f);
      const float scale = n <= 1.f ? 1.f : (2.f - 1.f / n) / n;
      for (int d = 0; d < 3; ++d) c[d] = c[d] * scale;
    }
    bool valid = true;
    for (int d = 0; d < 3; ++d) {
      float v = (c[d] / extent + 1.f) * 0.5f;
      if (contraction == kNone) {
        valid = valid && v >= 0.f && v <= 1.f;  // false for NaN
      } else {
        valid = valid && std::isfinite(v);
      }
      if (std::isnan(v)) v = 0.5f;
      u[d] = v < 0.f ? 0.f : (v > 1.f ? 1.f : v);
    }
    if (observed != nullptr) valid = valid && observed[cell(u, ro)];
    if (occupied != nullptr) valid = valid && occupied[cell(u, rc)];
    return valid;
  }

  static inline int64_t cell(const float* u, int64_t r) {
    int64_t i[3];
    for (int d = 0; d < 3; ++d) {
      int64_t v = static_cast<int64_t>(u[d] * static_cast<float>(r));
      i[d] = v < 0 ? 0 : (v > r - 1 ? r - 1 : v);
    }
    return (i[0] * r + i[1]) * r + i[2];
  }
};

Space make_space(int64_t contraction, double extent, const at::Tensor& observed, const at::Tensor& occupied) {
  Space sp{contraction, static_cast<float>(extent), nullptr, 0, nullptr, 0};
  TORCH_CHECK(contraction >= 0 && contraction <= 2, "space: contraction code must be 0 (none), 1 (linf) or 2 (l2)");
  if (observed.numel() > 0) {
    TORCH_CHECK(observed.scalar_type() == at::kBool && observed.is_contiguous() && observed.dim() == 3,
                "space: observed must be a contiguous bool [R, R, R]");
    sp.observed = observed.data_ptr<bool>();
    sp.ro = observed.size(0);
  }
  if (occupied.numel() > 0) {
    TORCH_CHECK(occupied.scalar_type() == at::kBool && occupied.is_contiguous() && occupied.dim() == 3,
                "space: occupied must be a contiguous bool [R, R, R]");
    sp.occupied = occupied.data_ptr<bool>();
    sp.rc = occupied.size(0);
  }
  return sp;
}

void space_forward(const at::Tensor& x, int64_t contraction, double extent, const at::Tensor& observed,
                   const at::Tensor& occupied, at::Tensor u, at::Tensor valid) {
  check_points(x, "space_forward");
  check_points(u, "space_forward (u)");
  TORCH_CHECK(valid.scalar_type() == at::kBool && valid.is_contiguous() && valid.numel() == x.size(0),
              "space_forward: valid must be a contiguous bool [N]");
  const Space sp = make_space(contraction, extent, observed, occupied);
  const float* xp = x.data_ptr<float>();
  float* up = u.data_ptr<float>();
  bool* vp = valid.data_ptr<bool>();
  at::parallel_for(0, x.size(0), kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) vp[i] = sp.map(xp + 3 * i, up + 3 * i);
  });
}

// ---------------------------------------------------------------------------------------------------
// One proposal level without gradients (rendering): density of a 1-channel proposal grid at the midpoints
// of each ray's intervals, rendering weights, and inverse-CDF resampling of the next intervals.
// lift3d.render.renderer.render_rays' proposal loop (training=False) in one pass per ray:
// samplers.spacing_fn_inv, volume.interval_midpoints, SceneSpace, ProposalGrid (exp(min(raw + bias, 20))
// times valid), volume.render_weights and samplers.sample_pdf (jitter off). Running sums in double, as
// torch's CPU cumsum accumulates float in double.

inline float spacing_inv(float s, bool lindisp) {
  if (!lindisp) return s;
  return s < 0.5f ? 2.f * s : 0.5f / std::max(1.f - s, 1e-7f);
}

void proposal_resample(const at::Tensor& origins, const at::Tensor& dirs, const at::Tensor& edges, bool lindisp,
                       const at::Tensor& table, int64_t resolution, double density_bias, int64_t contraction,
                       double extent, const at::Tensor& observed, const at::Tensor& occupied, double padding,
                       at::Tensor new_edges) {
  check_points(origins, "proposal_resample (origins)");
  check_points(dirs, "proposal_resample (dirs)");
  const int64_t n_rays = origins.size(0);
  TORCH_CHECK(edges.scalar_type() == at::kFloat && edges.is_contiguous() && edges.dim() == 2 &&
                  edges.size(0) == n_rays && edges.size(1) >= 2,
              "proposal_resample: edges must be a contiguous float32 [R, P+1]");
  TORCH_CHECK(new_edges.scalar_type() == at::kFloat && new_edges.is_contiguous() && new_edges.dim() == 2 &&
                  new_edges.size(0) == n_rays && new_edges.size(1) >= 2,
              "proposal_resample: new_edges must be a contiguous float32 [R, S+1]");
  TORCH_CHECK(table.scalar_type() == at::kFloat && table.is_contiguous() && table.size(1) == 1 &&
                  table.size(0) == resolution * resolution * resolution,
              "proposal_resample: table must be a contiguous float32 [R^3, 1]");
  const Space sp = make_space(contraction, extent, observed, occupied);
  const int64_t p = edges.size(1) - 1, s_out = new_edges.size(1) - 1;
  const float* op = origins.data_ptr<float>();
  const float* dp = dirs.data_ptr<float>();
  const float* ep = edges.data_ptr<float>();
  const float* tp = table.data_ptr<float>();
  float* np_ = new_edges.data_ptr<float>();
  const float bias = static_cast<float>(density_bias);
  const float pad = static_cast<float>(padding) / static_cast<float>(p);
  at::parallel_for(0, n_rays, 64, [&](int64_t begin, int64_t end) {
    std::vector<float> t(p + 1), w(p), cdf(p + 1);
    Corners c;
    for (int64_t r = begin; r < end; ++r) {
      const float* e = ep + r * (p + 1);
      for (int64_t i = 0; i <= p; ++i) t[i] = spacing_inv(e[i], lindisp);
      double cum = 0.0;  // optical depth before interval i
      for (int64_t i = 0; i < p; ++i) {
        const float mid = 0.5f * (t[i + 1] + t[i]);
        const float delta = std::max(t[i + 1] - t[i], 0.f);
        float x[3], u[3];
        for (int d = 0; d < 3; ++d) x[d] = op[3 * r + d] + dp[3 * r + d] * mid;
        float sigma = 0.f;
        if (sp.map(x, u)) {
          corners_of(u, resolution, c);
          float raw = 0.f;
          for (int k = 0; k < 8; ++k) raw += c.w[k] * tp[c.idx[k]];
          sigma = std::exp(std::min(raw + bias, 20.f));
        }
        float tau = sigma * delta;
        if (std::isnan(tau)) tau = 0.f;
        tau = tau < 0.f ? 0.f : (tau > 1e4f ? 1e4f : tau);
        const float trans = std::exp(-static_cast<float>(cum));
        w[i] = trans * -std::expm1(-tau);
        cum += tau;
      }
      // sample_pdf, deterministic midpoints of the CDF.
      double total = 0.0;
      for (int64_t i = 0; i < p; ++i) total += static_cast<double>(w[i] + pad);
      cdf[0] = 0.f;
      double run = 0.0;
      for (int64_t i = 0; i < p; ++i) {
        run += static_cast<double>((w[i] + pad) / static_cast<float>(total));
        cdf[i + 1] = std::min(static_cast<float>(run), 1.f);
      }
      cdf[p] = 1.f;
      float* out = np_ + r * (s_out + 1);
      int64_t j = 0;  // searchsorted(right=True): first index with cdf > q
      for (int64_t k = 0; k <= s_out; ++k) {
        const float q = static_cast<float>(k) / static_cast<float>(s_out);
        while (j <= p && cdf[j] <= q) ++j;
        const int64_t below = std::min(std::max<int64_t>(j - 1, 0), p), above = std::min(j, p);
        const float c0 = cdf[below], c1 = cdf[above];
        float frac = (q - c0) / (c1 - c0);
        if (!std::isfinite(frac)) frac = 0.f;
        frac = frac < 0.f ? 0.f : (frac > 1.f ? 1.f : frac);
        out[k] = e[below] + frac * (e[above] - e[below]);
      }
    }
  });
}

// ---------------------------------------------------------------------------------------------------
// Inference of a small ReLU MLP, fully fused: a block of rows goes through every layer while it stays in
// the L1 cache, and no intermediate activation is ever written to memory. MKL's sgemm reaches only a third
// of the FMA rate on these shapes (K, N = 3..256 with tens of thousands of rows; an output layer of 3
// columns runs at a few GFLOP/s) and each layer allocates its output; this kernel keeps 6 rows x 16
// columns of accumulators in registers (GCC vector extensions: AVX2/AVX-512 with -march=native, NEON or
// SSE elsewhere).

typedef float v8f __attribute__((vector_size(32)));
constexpr int kRows = 6;  // rows per register block (6 x 16 accumulators + 2 weight vectors + 1 broadcast: 15 of AVX2's 16 registers)
constexpr int64_t kBlockRows = 8 * kRows;  // rows per cache block of the MLP kernels

struct Layer {
  std::vector<float> w;  // [K][Npad] (input-major, columns padded to a multiple of 16 with zeros)
  std::vector<float> b;  // [Npad]
  int64_t k = 0, n = 0, npad = 0;
};

// acc[kRows][Npad] = in[kRows][K] @ W + b, then ReLU when `relu`; `in` rows are `ldi` apart.
inline void layer_block(const Layer& L, const float* in, int64_t ldi, float* out, int64_t ldo, bool relu) {
  for (int64_t j0 = 0; j0 < L.npad; j0 += 16) {
    v8f acc[kRows][2];
    v8f b0, b1;
    __builtin_memcpy(&b0, &L.b[j0], sizeof(v8f));
    __builtin_memcpy(&b1, &L.b[j0 + 8], sizeof(v8f));
    for (int r = 0; r < kRows; ++r) {
      acc[r][0] = b0;
      acc[r][1] = b1;
    }
    const float* wp = L.w.data() + j0;
    for (int64_t k = 0; k < L.k; ++k, wp += L.npad) {
      v8f w0, w1;
      __builtin_memcpy(&w0, wp, sizeof(v8f));
      __builtin_memcpy(&w1, wp + 8, sizeof(v8f));
      for (int r = 0; r < kRows; ++r) {
        const float x = in[r * ldi + k];
        const v8f xv = {x, x, x, x, x, x, x, x};
        acc[r][0] += xv * w0;
        acc[r][1] += xv * w1;
      }
    }
    for (int r = 0; r < kRows; ++r) {
      if (relu) {
        const v8f zero = {0, 0, 0, 0, 0, 0, 0, 0};
        acc[r][0] = acc[r][0] > zero ? acc[r][0] : zero;
        acc[r][1] = acc[r][1] > zero ? acc[r][1] : zero;
      }
      __builtin_memcpy(out + r * ldo + j0, &acc[r][0], sizeof(v8f));
      __builtin_memcpy(out + r * ldo + j0 + 8, &acc[r][1], sizeof(v8f));
    }
  }
}

inline int64_t round_up(int64_t v, int64_t m) { return (v + m - 1) / m * m; }

// A torch.nn.Linear layer (weight [N, K], bias [N]) in the forward layout of layer_block: W^T [K][Npad].
Layer pack_forward(const at::Tensor& weight, const at::Tensor& bias, int64_t k, size_t l) {
  const at::Tensor w = weight.contiguous(), b = bias.contiguous();
  TORCH_CHECK(w.device().is_cpu() && w.scalar_type() == at::kFloat && w.dim() == 2 && w.size(1) == k &&
                  b.scalar_type() == at::kFloat && b.numel() == w.size(0),
              "mlp: layer ", l, " does not fit its input (float32 weight [N, ", k, "], bias [N] expected)");
  Layer L;
  L.k = k;
  L.n = w.size(0);
  L.npad = round_up(L.n, 16);
  L.w.assign(L.k * L.npad, 0.f);
  L.b.assign(L.npad, 0.f);
  const float* wp = w.data_ptr<float>();
  for (int64_t o = 0; o < L.n; ++o)
    for (int64_t i = 0; i < L.k; ++i) L.w[i * L.npad + o] = wp[o * L.k + i];
  for (int64_t o = 0; o < L.n; ++o) L.b[o] = b.data_ptr<float>()[o];
  return L;
}

// The same layer for the backward pass, grad_in = grad_out @ W, in layer_block's layout: W [N][Kpad] (no
// bias), keeping only the first `cols` input columns.
Layer pack_backward(const at::Tensor& weight, int64_t cols) {
  const at::Tensor w = weight.contiguous();
  Layer L;
  L.k = w.size(0);
  L.n = cols;
  L.npad = round_up(cols, 16);
  L.w.assign(L.k * L.npad, 0.f);
  L.b.assign(L.npad, 0.f);
  const float* wp = w.data_ptr<float>();
  for (int64_t o = 0; o < L.k; ++o)
    for (int64_t i = 0; i < cols; ++i) L.w[o * L.npad + i] = wp[o * w.size(1) + i];
  return L;
}

std::vector<Layer> pack_mlp(const at::Tensor& x, const std::vector<at::Tensor>& weights,
                            const std::vector<at::Tensor>& biases, int64_t& widest) {
  TORCH_CHECK(x.device().is_cpu() && x.scalar_type() == at::kFloat && x.dim() == 2 && x.stride(1) == 1,
              "mlp: x must be a float32 CPU matrix with unit column stride");
  TORCH_CHECK(!weights.empty() && weights.size() == biases.size(), "mlp: one bias per weight");
  std::vector<Layer> layers;
  int64_t k = x.size(1);
  widest = round_up(k, 16);
  for (size_t l = 0; l < weights.size(); ++l) {
    layers.push_back(pack_forward(weights[l], biases[l], k, l));
    k = layers.back().n;
    widest = std::max(widest, layers.back().npad);
  }
  return layers;
}

void check_rows(const at::Tensor& t, int64_t n, int64_t cols, const char* name) {
  TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == at::kFloat && t.dim() == 2 && t.size(0) == n &&
                  t.size(1) >= cols && t.stride(1) == 1,
              name, ": expected a float32 CPU matrix [", n, ", >= ", cols, "] with unit column stride");
}

// Copy rows [r0, r0 + rows) of src (columns [0, cols)) into a zeroed block [kBlockRows][ld].
inline void load_block(const float* src, int64_t lds, int64_t r0, int64_t rows, int64_t cols, float* dst, int64_t ld) {
  std::fill(dst, dst + kBlockRows * ld, 0.f);
  for (int64_t r = 0; r < rows; ++r) std::copy(src + (r0 + r) * lds, src + (r0 + r) * lds + cols, dst + r * ld);
}

// out = MLP(x) for torch.nn.Linear weights [N_i, K_i] and biases [N_i], ReLU between layers; with `hidden`
// (a buffer per hidden layer, or empty) also every hidden layer's output after its ReLU. kBlockRows rows go
// through one layer before the next layer starts: the layer's weights stay in the L1 cache for all of them
// (the decoders' weights together do not fit).
void run_mlp_blocks(const at::Tensor& x, const std::vector<Layer>& layers, int64_t widest, at::Tensor out,
                    const std::vector<at::Tensor>& hidden) {
  const int64_t n = x.size(0);
  check_rows(out, n, layers.back().n, "mlp (out)");
  for (size_t l = 0; l < hidden.size(); ++l) check_rows(hidden[l], n, layers[l].n, "mlp (hidden)");
  if (n == 0) return;
  const float* xp = x.data_ptr<float>();
  const int64_t ldx = x.stride(0);
  std::vector<float*> dst(layers.size(), nullptr);  // where a layer's output goes (hidden: only when kept)
  std::vector<int64_t> ld(layers.size(), 0);
  for (size_t l = 0; l < layers.size(); ++l) {
    if (l + 1 < layers.size() && hidden.empty()) continue;
    const at::Tensor& t = l + 1 < layers.size() ? hidden[l] : out;
    dst[l] = t.data_ptr<float>();
    ld[l] = t.stride(0);
  }
  at::parallel_for(0, (n + kBlockRows - 1) / kBlockRows, 1, [&](int64_t begin, int64_t end) {
    std::vector<float> a(kBlockRows * widest), b(kBlockRows * widest);
    for (int64_t blk = begin; blk < end; ++blk) {
      const int64_t r0 = blk * kBlockRows, rows = std::min(kBlockRows, n - r0);
      load_block(xp, ldx, r0, rows, layers[0].k, a.data(), widest);
      float* cur = a.data();
      float* nxt = b.data();
      for (size_t l = 0; l < layers.size(); ++l) {
        for (int64_t r = 0; r < kBlockRows; r += kRows)
          layer_block(layers[l], cur + r * widest, widest, nxt + r * widest, widest, l + 1 < layers.size());
        if (dst[l] != nullptr)
          for (int64_t r = 0; r < rows; ++r)
            std::copy(nxt + r * widest, nxt + r * widest + layers[l].n, dst[l] + (r0 + r) * ld[l]);
        std::swap(cur, nxt);
      }
    }
  });
}

void mlp_forward(const at::Tensor& x, const std::vector<at::Tensor>& weights, const std::vector<at::Tensor>& biases,
                 at::Tensor out) {
  int64_t widest = 0;
  const std::vector<Layer> layers = pack_mlp(x, weights, biases, widest);
  run_mlp_blocks(x, layers, widest, out, {});
}

// ---------------------------------------------------------------------------------------------------
// Training of the same MLPs. The forward also keeps every hidden activation (after its ReLU) for the
// backward; the backward computes the weight and bias gradients and the gradient of the input's first
// `grad_x_cols` columns (the rest of a decoder's input, positional encodings or detached features, needs
// none), a block of rows at a time while the block stays in the cache. Weight gradients are summed per
// chunk of rows and the chunks added in a fixed order, so the result does not depend on the thread count.

constexpr int64_t kChunks = 8;             // row chunks of the weight-gradient sums

// dw[o][i] += sum_r g[r][o] a[r][i] over a block of kBlockRows rows; o < rows of dw (a multiple of kRows),
// i < ldw (a multiple of 16). g rows are ldg apart, a rows lda apart.
inline void weight_grad_block(const float* g, int64_t ldg, const float* a, int64_t lda, float* dw, int64_t o_rows,
                              int64_t ldw) {
  for (int64_t o0 = 0; o0 < o_rows; o0 += kRows) {
    for (int64_t i0 = 0; i0 < ldw; i0 += 16) {
      v8f acc[kRows][2];
      for (int j = 0; j < kRows; ++j) {
        __builtin_memcpy(&acc[j][0], dw + (o0 + j) * ldw + i0, sizeof(v8f));
        __builtin_memcpy(&acc[j][1], dw + (o0 + j) * ldw + i0 + 8, sizeof(v8f));
      }
      for (int64_t r = 0; r < kBlockRows; ++r) {
        v8f a0, a1;
        __builtin_memcpy(&a0, a + r * lda + i0, sizeof(v8f));
        __builtin_memcpy(&a1, a + r * lda + i0 + 8, sizeof(v8f));
        const float* gr = g + r * ldg + o0;
        for (int j = 0; j < kRows; ++j) {
          const float x = gr[j];
          const v8f xv = {x, x, x, x, x, x, x, x};
          acc[j][0] += xv * a0;
          acc[j][1] += xv * a1;
        }
      }
      for (int j = 0; j < kRows; ++j) {
        __builtin_memcpy(dw + (o0 + j) * ldw + i0, &acc[j][0], sizeof(v8f));
        __builtin_memcpy(dw + (o0 + j) * ldw + i0 + 8, &acc[j][1], sizeof(v8f));
      }
    }
  }
}

// out = MLP(x) as mlp_forward, and hidden[l] = the activation after hidden layer l's ReLU.
void mlp_forward_train(const at::Tensor& x, const std::vector<at::Tensor>& weights,
                       const std::vector<at::Tensor>& biases, at::Tensor out, std::vector<at::Tensor> hidden) {
  int64_t widest = 0;
  const std::vector<Layer> layers = pack_mlp(x, weights, biases, widest);
  TORCH_CHECK(hidden.size() + 1 == layers.size(), "mlp_forward_train: one hidden buffer per hidden layer");
  run_mlp_blocks(x, layers, widest, out, hidden);
}

// Gradients of mlp_forward_train's output: grad_w[l] = dL/dW_l and grad_b[l] = dL/db_l (overwritten), and
// when grad_x_cols > 0 grad_x = dL/dx in its first grad_x_cols columns, 0 in the others.
void mlp_backward(const at::Tensor& x, const std::vector<at::Tensor>& hidden, const std::vector<at::Tensor>& weights,
                  const at::Tensor& grad_out, std::vector<at::Tensor> grad_w, std::vector<at::Tensor> grad_b,
                  at::Tensor grad_x, int64_t grad_x_cols) {
  TORCH_CHECK(x.device().is_cpu() && x.scalar_type() == at::kFloat && x.dim() == 2 && x.stride(1) == 1,
              "mlp_backward: x must be a float32 CPU matrix with unit column stride");
  const size_t n_layers = weights.size();
  TORCH_CHECK(n_layers > 0 && hidden.size() + 1 == n_layers && grad_w.size() == n_layers && grad_b.size() == n_layers,
              "mlp_backward: one weight, weight gradient and bias gradient per layer, one hidden buffer per hidden layer");
  const int64_t n = x.size(0);
  std::vector<int64_t> k(n_layers), m(n_layers), kpad(n_layers), mpad(n_layers);
  std::vector<Layer> back(n_layers);  // grad_in = grad_out @ W (layer 0: only the first grad_x_cols inputs)
  int64_t widest = 16;
  for (size_t l = 0; l < n_layers; ++l) {
    const at::Tensor& w = weights[l];
    TORCH_CHECK(w.device().is_cpu() && w.scalar_type() == at::kFloat && w.dim() == 2 &&
                    w.size(1) == (l == 0 ? x.size(1) : m[l - 1]),
                "mlp_backward: layer ", l, " does not fit its input");
    k[l] = w.size(1);
    m[l] = w.size(0);
    kpad[l] = round_up(k[l], 16);
    mpad[l] = std::max(round_up(m[l], 16), round_up(m[l], kRows));
    widest = std::max({widest, kpad[l], mpad[l]});
    TORCH_CHECK(grad_w[l].scalar_type() == at::kFloat && grad_w[l].is_contiguous() && grad_w[l].sizes() == w.sizes() &&
                    grad_b[l].scalar_type() == at::kFloat && grad_b[l].is_contiguous() && grad_b[l].numel() == m[l],
                "mlp_backward: gradient ", l, " must be contiguous float32 of its parameter's shape");
    if (l > 0) {
      check_rows(hidden[l - 1], n, k[l], "mlp_backward (hidden)");
      back[l] = pack_backward(w, k[l]);
    }
  }
  TORCH_CHECK(grad_x_cols >= 0 && grad_x_cols <= x.size(1), "mlp_backward: grad_x_cols out of range");
  if (grad_x_cols > 0) {
    check_rows(grad_x, n, x.size(1), "mlp_backward (grad_x)");
    back[0] = pack_backward(weights[0], grad_x_cols);
  }
  check_rows(grad_out, n, m.back(), "mlp_backward (grad_out)");
  // Per chunk of rows: the weight gradients [mpad][kpad] and bias gradients [mpad] of every layer.
  std::vector<int64_t> offset(n_layers + 1, 0);
  for (size_t l = 0; l < n_layers; ++l) offset[l + 1] = offset[l] + mpad[l] * kpad[l] + mpad[l];
  const int64_t blocks = (n + kBlockRows - 1) / kBlockRows;
  const int64_t chunks = std::max<int64_t>(1, std::min(kChunks, blocks));
  std::vector<float> sums(chunks * offset[n_layers], 0.f);
  const float* xp = x.data_ptr<float>();
  const float* gp = grad_out.data_ptr<float>();
  const int64_t ldgo = grad_out.stride(0), ldx = x.stride(0);
  float* gx = grad_x_cols > 0 ? grad_x.data_ptr<float>() : nullptr;
  const int64_t ldgx = grad_x_cols > 0 ? grad_x.stride(0) : 0;
  std::vector<const float*> hp;
  std::vector<int64_t> ldh;
  for (const auto& h : hidden) {
    hp.push_back(h.data_ptr<float>());
    ldh.push_back(h.stride(0));
  }
  at::parallel_for(0, chunks, 1, [&](int64_t cbegin, int64_t cend) {
    std::vector<float> g(kBlockRows * widest), gin(kBlockRows * widest), a(kBlockRows * widest);
    for (int64_t c = cbegin; c < cend; ++c) {
      float* acc = sums.data() + c * offset[n_layers];
      for (int64_t blk = blocks * c / chunks; blk < blocks * (c + 1) / chunks; ++blk) {
        const int64_t r0 = blk * kBlockRows, rows = std::min(kBlockRows, n - r0);
        load_block(gp, ldgo, r0, rows, m.back(), g.data(), widest);
        for (size_t l = n_layers; l-- > 0;) {
          if (l == 0) {
            load_block(xp, ldx, r0, rows, k[0], a.data(), widest);
          } else {
            load_block(hp[l - 1], ldh[l - 1], r0, rows, k[l], a.data(), widest);
          }
          float* dw = acc + offset[l];
          float* db = dw + mpad[l] * kpad[l];
          weight_grad_block(g.data(), widest, a.data(), widest, dw, round_up(m[l], kRows), kpad[l]);
          for (int64_t r = 0; r < rows; ++r)
            for (int64_t o = 0; o < m[l]; ++o) db[o] += g[r * widest + o];
          if (l == 0 && grad_x_cols == 0) break;
          for (int64_t r = 0; r < kBlockRows; r += kRows)
            layer_block(back[l], g.data() + r * widest, widest, gin.data() + r * widest, widest, false);
          if (l == 0) {
            for (int64_t r = 0; r < rows; ++r) {
              float* dst = gx + (r0 + r) * ldgx;
              std::copy(gin.data() + r * widest, gin.data() + r * widest + grad_x_cols, dst);
              std::fill(dst + grad_x_cols, dst + k[0], 0.f);  // the columns that need no gradient
            }
            break;
          }
          // Through the ReLU of hidden layer l - 1: its output (now in `a`) was positive where it passed.
          for (int64_t r = 0; r < rows; ++r) {
            float* gr = gin.data() + r * widest;
            const float* ar = a.data() + r * widest;
            // A select, not a conditional store: compilers turn the latter into masked stores, which are slow
            // on AMD CPUs (a seventh of the backward's time on Zen 3).
            for (int64_t i = 0; i < k[l]; ++i) gr[i] = ar[i] > 0.f ? gr[i] : 0.f;
          }
          std::swap(g, gin);
        }
      }
    }
  });
  // Chunks added in order (deterministic), written to the gradients' own layout.
  for (size_t l = 0; l < n_layers; ++l) {
    float* gw = grad_w[l].data_ptr<float>();
    float* gb = grad_b[l].data_ptr<float>();
    for (int64_t o = 0; o < m[l]; ++o) {
      for (int64_t i = 0; i < k[l]; ++i) {
        float s = 0.f;
        for (int64_t c = 0; c < chunks; ++c) s += sums[c * offset[n_layers] + offset[l] + o * kpad[l] + i];
        gw[o * k[l] + i] = s;
      }
      float s = 0.f;
      for (int64_t c = 0; c < chunks; ++c) s += sums[c * offset[n_layers] + offset[l] + mpad[l] * kpad[l] + o];
      gb[o] = s;
    }
  }
}

// ---------------------------------------------------------------------------------------------------
// Rendering without gradients: the grid field's density and geometry features at the samples of each ray,
// taken in order along the ray, only at valid samples, until the ray's optical depth reaches `max_depth`
// (transmittance below exp(-max_depth): every later sample's weight would be smaller; early ray
// termination). What lift3d.render.renderer.geometry_where_needed does block by block with a dozen operators
// per block, in one pass: grid lookup of every level, positional encoding, the density decoder (a few rows
// at a time: the ray's next kRows valid samples), the density activation, the termination test. Skipped
// samples get sigma 0 and zero features. The arithmetic is GridField.geometry's.

constexpr int64_t kAhead = 2;  // samples ahead on a ray whose grid rows are prefetched

void march_density(const at::Tensor& u, const at::Tensor& valid, const at::Tensor& deltas,
                   const std::vector<at::Tensor>& tables, const std::vector<int64_t>& resolutions, int64_t levels,
                   int64_t frequencies, const std::vector<at::Tensor>& weights, const std::vector<at::Tensor>& biases,
                   double density_bias, double max_depth, at::Tensor sigma, at::Tensor geo) {
  check_points(u, "march_density");
  TORCH_CHECK(valid.scalar_type() == at::kBool && valid.is_contiguous() && valid.dim() == 2,
              "march_density: valid must be a contiguous bool [R, S]");
  const int64_t n_rays = valid.size(0), n_samples = valid.size(1);
  TORCH_CHECK(u.size(0) == n_rays * n_samples, "march_density: u must have R * S rows");
  TORCH_CHECK(deltas.scalar_type() == at::kFloat && deltas.is_contiguous() && deltas.sizes() == valid.sizes(),
              "march_density: deltas must be a contiguous float32 [R, S]");
  TORCH_CHECK(sigma.scalar_type() == at::kFloat && sigma.is_contiguous() && sigma.sizes() == valid.sizes(),
              "march_density: sigma must be a contiguous float32 [R, S]");
  TORCH_CHECK(!tables.empty() && tables.size() == resolutions.size() && static_cast<int64_t>(tables.size()) <= levels,
              "march_density: one resolution per (active) table, at most `levels` tables");
  const int64_t channels = tables[0].size(1);
  std::vector<const float*> tptr;
  for (size_t l = 0; l < tables.size(); ++l) {
    const auto& t = tables[l];
    TORCH_CHECK(t.device().is_cpu() && t.scalar_type() == at::kFloat && t.is_contiguous() && t.size(1) == channels &&
                    t.size(0) == resolutions[l] * resolutions[l] * resolutions[l],
                "march_density: table ", l, " must be a contiguous float32 [R^3, C]");
    tptr.push_back(t.data_ptr<float>());
  }
  const int64_t grid_dim = levels * channels, in_dim = grid_dim + 3 * (1 + 2 * frequencies);
  TORCH_CHECK(weights[0].dim() == 2 && weights[0].size(1) == in_dim,
              "march_density: the decoder's input must be the grid features and the positional encoding");
  int64_t widest = 0;
  const std::vector<Layer> layers = pack_mlp(u.new_empty({0, in_dim}), weights, biases, widest);
  const int64_t feat = layers.back().n - 1;
  TORCH_CHECK(feat >= 0, "march_density: the decoder has no density output");
  check_rows(geo, n_rays * n_samples, feat, "march_density (geo)");
  const float* up = u.data_ptr<float>();
  const bool* vp = valid.data_ptr<bool>();
  const float* dp = deltas.data_ptr<float>();
  float* sp = sigma.data_ptr<float>();
  float* gp = geo.data_ptr<float>();
  const int64_t ldg = geo.stride(0);
  const float bias = static_cast<float>(density_bias);
  const size_t active = tables.size();
  at::parallel_for(0, n_rays, 16, [&](int64_t begin, int64_t end) {
    std::vector<float> a(kRows * widest, 0.f), b(kRows * widest, 0.f);
    Corners c;
    int64_t pending[kRows];
    float raw_direct[kRows];
    for (int64_t r = begin; r < end; ++r) {
      const int64_t base = r * n_samples;
      std::fill(sp + base, sp + base + n_samples, 0.f);
      for (int64_t i = 0; i < n_samples; ++i) std::fill(gp + (base + i) * ldg, gp + (base + i) * ldg + feat, 0.f);
      double optical = 0.0;
      int64_t count = 0;
      for (int64_t i = 0; i <= n_samples && optical < max_depth; ++i) {
        if (i < n_samples) {
          if (!vp[base + i]) continue;
          // The sample's decoder input: grid features of every level (inactive fine levels: 0), then the encoding.
          float* row = a.data() + count * widest;
          const float* ui = up + 3 * (base + i);
          // Fetch the corner rows of a sample a few ahead on the ray (the fine levels do not fit in the
          // cache; the loads overlap with this sample's work instead of waiting one after the other).
          if (i + kAhead < n_samples) {
            Corners ahead;
            for (size_t l = 0; l < active; ++l) {
              corners_of(up + 3 * (base + i + kAhead), resolutions[l], ahead);
              for (int k = 0; k < 8; k += 2) __builtin_prefetch(tptr[l] + ahead.idx[k] * channels);
            }
          }
          for (size_t l = 0; l < active; ++l) {
            corners_of(ui, resolutions[l], c);
            lerp_level(tptr[l], c, row + static_cast<int64_t>(l) * channels, channels);
          }
          std::fill(row + active * channels, row + grid_dim, 0.f);
          positional_row(ui, frequencies, row + grid_dim);
          // The first channel of every grid level adds to the raw density directly (GridField.geometry).
          float direct = 0.f;
          for (int64_t l = 0; l < levels; ++l) direct += row[l * channels];
          raw_direct[count] = direct;
          pending[count++] = i;
          if (count < kRows) continue;
        }
        if (count == 0) break;
        // Decode the pending samples (rows past `count` hold stale inputs; their outputs are not read).
        float* cur = a.data();
        float* nxt = b.data();
        for (size_t l = 0; l < layers.size(); ++l) {
          layer_block(layers[l], cur, widest, nxt, widest, l + 1 < layers.size());
          std::swap(cur, nxt);
        }
        for (int64_t j = 0; j < count; ++j) {
          const float* out = cur + j * widest;
          const float s = std::exp(std::min(out[0] + raw_direct[j] + bias, 20.f));
          const int64_t k = base + pending[j];
          sp[k] = s;
          std::copy(out + 1, out + 1 + feat, gp + k * ldg);
          double tau = static_cast<double>(s) * static_cast<double>(dp[k]);
          if (std::isnan(tau)) tau = 0.0;
          optical += std::min(std::max(tau, 0.0), 1e30);
        }
        count = 0;
      }
    }
  });
}

// ---------------------------------------------------------------------------------------------------
// Rendering without gradients: decoders at the chosen samples of each ray, weighted and summed per ray
// (C = sum_i w_i c_i), in one pass instead of gathering inputs, concatenating, decoding, multiplying and
// adding per ray with an operator each. A sample's decoder input is, by `layout`,
//   0 (colour):  [geo[sample] | SH(dirs[ray])]                      (GridField.color)
//   1 (labels):  [grid(u[sample]) | PE(u[sample]) | geo[sample]]    (GridField.labels)
// and every decoder of the list (the semantic and the instance head) reads the same input. The samples of a
// ray are consecutive rows (ray_start[r] .. ray_start[r + 1]); rows are decoded kRows at a time across ray
// boundaries, and each task owns whole rays, so the sums need no synchronisation.

void decode_composite(const at::Tensor& ray_start, const at::Tensor& sample, const at::Tensor& weight,
                      const at::Tensor& u, const at::Tensor& geo, const at::Tensor& dirs, int64_t layout,
                      int64_t sh_degree, const std::vector<at::Tensor>& tables, const std::vector<int64_t>& resolutions,
                      int64_t levels, int64_t frequencies, const std::vector<at::Tensor>& weights,
                      const std::vector<at::Tensor>& biases, const std::vector<int64_t>& layer_counts, bool sigmoid,
                      std::vector<at::Tensor> outs) {
  TORCH_CHECK(layout == 0 || layout == 1, "decode_composite: layout must be 0 (colour) or 1 (labels)");
  TORCH_CHECK(ray_start.scalar_type() == at::kLong && ray_start.is_contiguous() && ray_start.dim() == 1,
              "decode_composite: ray_start must be a contiguous int64 [R + 1]");
  const int64_t n_rays = ray_start.size(0) - 1;
  const int64_t k_rows = sample.numel();
  TORCH_CHECK(sample.scalar_type() == at::kLong && sample.is_contiguous() && weight.scalar_type() == at::kFloat &&
                  weight.is_contiguous() && weight.numel() == k_rows,
              "decode_composite: sample (int64) and weight (float32) must be contiguous [K]");
  TORCH_CHECK(geo.scalar_type() == at::kFloat && geo.dim() == 2 && geo.stride(1) == 1,
              "decode_composite: geo must be float32 [N, F] with unit column stride");
  const int64_t feat = geo.size(1);
  int64_t in_dim = feat;
  std::vector<const float*> tptr;
  int64_t channels = 0;
  if (layout == 0) {
    check_points(dirs, "decode_composite (dirs)");
    TORCH_CHECK(dirs.size(0) == n_rays && sh_degree >= 0 && sh_degree <= 3,
                "decode_composite: a direction per ray and an SH degree in 0..3");
    in_dim += (sh_degree + 1) * (sh_degree + 1);
  } else {
    check_points(u, "decode_composite (u)");
    TORCH_CHECK(u.size(0) == geo.size(0), "decode_composite: u and geo need a row per sample each");
    TORCH_CHECK(!tables.empty() && tables.size() == resolutions.size() && static_cast<int64_t>(tables.size()) <= levels,
                "decode_composite: one resolution per (active) table");
    channels = tables[0].size(1);
    for (size_t l = 0; l < tables.size(); ++l) {
      const auto& t = tables[l];
      TORCH_CHECK(t.scalar_type() == at::kFloat && t.is_contiguous() && t.size(1) == channels &&
                      t.size(0) == resolutions[l] * resolutions[l] * resolutions[l],
                  "decode_composite: table ", l, " must be a contiguous float32 [R^3, C]");
      tptr.push_back(t.data_ptr<float>());
    }
    in_dim += levels * channels + 3 * (1 + 2 * frequencies);
  }
  TORCH_CHECK(!layer_counts.empty() && outs.size() == layer_counts.size(), "decode_composite: one output per decoder");
  std::vector<std::vector<Layer>> decoders;
  int64_t widest = round_up(in_dim, 16);
  size_t first = 0;
  const at::Tensor no_rows = geo.new_empty({0, in_dim});
  for (size_t m = 0; m < layer_counts.size(); ++m) {
    const std::vector<at::Tensor> wm(weights.begin() + first, weights.begin() + first + layer_counts[m]);
    const std::vector<at::Tensor> bm(biases.begin() + first, biases.begin() + first + layer_counts[m]);
    first += layer_counts[m];
    int64_t wide = 0;
    decoders.push_back(pack_mlp(no_rows, wm, bm, wide));
    widest = std::max(widest, wide);
    check_rows(outs[m], n_rays, decoders.back().back().n, "decode_composite (out)");
  }
  const int64_t* sp = ray_start.data_ptr<int64_t>();
  const int64_t* smp = sample.data_ptr<int64_t>();
  TORCH_CHECK(sp[0] == 0 && sp[n_rays] == k_rows, "decode_composite: ray_start must run from 0 to K");
  for (int64_t r = 0; r < n_rays; ++r)
    TORCH_CHECK(sp[r] <= sp[r + 1], "decode_composite: ray_start must be non-decreasing");
  for (int64_t k = 0; k < k_rows; ++k)
    TORCH_CHECK(smp[k] >= 0 && smp[k] < geo.size(0), "decode_composite: a sample index outside geo's rows");
  const float* wp = weight.data_ptr<float>();
  const float* up = layout == 1 ? u.data_ptr<float>() : nullptr;
  const float* gp = geo.data_ptr<float>();
  const int64_t ldg = geo.stride(0);
  const float* dp = layout == 0 ? dirs.data_ptr<float>() : nullptr;
  std::vector<float*> op;
  std::vector<int64_t> ldo;
  for (auto& o : outs) {
    op.push_back(o.data_ptr<float>());
    ldo.push_back(o.stride(0));
  }
  const size_t active = tptr.size();
  at::parallel_for(0, n_rays, 64, [&](int64_t rb, int64_t re) {
    // kBlockRows rows at a time go through each layer while its weights stay in the L1 cache.
    std::vector<float> in(kBlockRows * widest, 0.f), a(kBlockRows * widest), b(kBlockRows * widest);
    std::vector<int64_t> ray_of(kBlockRows);
    for (size_t m = 0; m < decoders.size(); ++m)
      for (int64_t r = rb; r < re; ++r) std::fill(op[m] + r * ldo[m], op[m] + r * ldo[m] + decoders[m].back().n, 0.f);
    Corners c;
    int64_t ray = rb;
    const int64_t row_end = sp[re];
    for (int64_t row0 = sp[rb]; row0 < row_end; row0 += kBlockRows) {
      const int64_t count = std::min<int64_t>(kBlockRows, row_end - row0);
      const int64_t groups = (count + kRows - 1) / kRows * kRows;  // rows decoded (past `count`: stale, unread)
      for (int64_t j = 0; j < count; ++j) {
        const int64_t k = row0 + j;
        while (sp[ray + 1] <= k) ++ray;
        ray_of[j] = ray;
        float* row = in.data() + j * widest;
        const int64_t s = smp[k];
        if (layout == 0) {
          std::copy(gp + s * ldg, gp + s * ldg + feat, row);
          sh_row(dp + 3 * ray, sh_degree, row + feat);
        } else {
          const float* us = up + 3 * s;
          for (size_t l = 0; l < active; ++l) {
            corners_of(us, resolutions[l], c);
            lerp_level(tptr[l], c, row + static_cast<int64_t>(l) * channels, channels);
          }
          std::fill(row + active * channels, row + levels * channels, 0.f);
          positional_row(us, frequencies, row + levels * channels);
          std::copy(gp + s * ldg, gp + s * ldg + feat, row + in_dim - feat);
        }
      }
      for (size_t m = 0; m < decoders.size(); ++m) {
        const float* cur = in.data();
        float* nxt = a.data();
        for (size_t l = 0; l < decoders[m].size(); ++l) {
          for (int64_t r = 0; r < groups; r += kRows)
            layer_block(decoders[m][l], cur + r * widest, widest, nxt + r * widest, widest, l + 1 < decoders[m].size());
          cur = nxt;
          nxt = nxt == a.data() ? b.data() : a.data();
        }
        const int64_t n_out = decoders[m].back().n;
        for (int64_t j = 0; j < count; ++j) {
          const float w = wp[row0 + j];
          float* dst = op[m] + ray_of[j] * ldo[m];
          const float* y = cur + j * widest;
          for (int64_t o = 0; o < n_out; ++o) dst[o] += w * (sigmoid ? 1.f / (1.f + std::exp(-y[o])) : y[o]);
        }
      }
    }
  });
}

// Operators torch.ops.lift3d.* (registered with the dispatcher rather than pybind11: the build then needs
// only ATen's headers and compiles in a third of the time).
TORCH_LIBRARY(lift3d, m) {
  m.def("grid_forward(Tensor u, Tensor[] tables, int[] resolutions, Tensor(a!) out, int col) -> ()", &grid_forward);
  m.def("grid_backward(Tensor u, Tensor grad_out, int col, Tensor(a!)[] grads, int[] resolutions) -> ()",
        &grid_backward);
  m.def("positional_forward(Tensor u, int frequencies, Tensor(a!) out, int col) -> ()", &positional_forward);
  m.def("sh_forward(Tensor dirs, int degree, Tensor(a!) out, int col) -> ()", &sh_forward);
  m.def("space_forward(Tensor x, int contraction, float extent, Tensor observed, Tensor occupied, Tensor(a!) u, "
        "Tensor(b!) valid) -> ()", &space_forward);
  m.def("proposal_resample(Tensor origins, Tensor dirs, Tensor edges, bool lindisp, Tensor table, int resolution, "
        "float density_bias, int contraction, float extent, Tensor observed, Tensor occupied, float padding, "
        "Tensor(a!) new_edges) -> ()", &proposal_resample);
  m.def("mlp_forward(Tensor x, Tensor[] weights, Tensor[] biases, Tensor(a!) out) -> ()", &mlp_forward);
  m.def("march_density(Tensor u, Tensor valid, Tensor deltas, Tensor[] tables, int[] resolutions, int levels, "
        "int frequencies, Tensor[] weights, Tensor[] biases, float density_bias, float max_depth, Tensor(a!) sigma, "
        "Tensor(b!) geo) -> ()", &march_density);
  m.def("decode_composite(Tensor ray_start, Tensor sample, Tensor weight, Tensor u, Tensor geo, Tensor dirs, "
        "int layout, int sh_degree, Tensor[] tables, int[] resolutions, int levels, int frequencies, Tensor[] weights, "
        "Tensor[] biases, int[] layer_counts, bool sigmoid, Tensor(a!)[] outs) -> ()", &decode_composite);
  m.def("tv_forward(Tensor[] tables, Tensor[] bases, int[] resolutions, Tensor(a!) means) -> ()", &tv_forward);
  m.def("tv_backward(Tensor[] tables, Tensor[] bases, int[] resolutions, Tensor grad_means, Tensor(a!)[] grads) -> ()",
        &tv_backward);
  m.def("mlp_forward_train(Tensor x, Tensor[] weights, Tensor[] biases, Tensor(a!) out, Tensor(b!)[] hidden) -> ()",
        &mlp_forward_train);
  m.def("mlp_backward(Tensor x, Tensor[] hidden, Tensor[] weights, Tensor grad_out, Tensor(a!)[] grad_w, "
        "Tensor(b!)[] grad_b, Tensor(c!) grad_x, int grad_x_cols) -> ()", &mlp_backward);
}
