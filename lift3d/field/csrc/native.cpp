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
        float* dst = row + static_cast<int64_t>(l) * channels;
        switch (channels) {
          case 1: lerp_row<1>(tptr[l], c, dst, 1); break;
          case 2: lerp_row<2>(tptr[l], c, dst, 2); break;
          case 4: lerp_row<4>(tptr[l], c, dst, 4); break;
          case 8: lerp_row<8>(tptr[l], c, dst, 8); break;
          default: lerp_row<0>(tptr[l], c, dst, channels);
        }
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
    for (int64_t i = begin; i < end; ++i) {
      float* row = op + i * ld + col;
      float x[3];
      for (int d = 0; d < 3; ++d) x[d] = up[3 * i + d] * 2.f - 1.f;
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
  });
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
  const float C0 = 0.28209479177387814f, C1 = 0.4886025119029199f;
  const float C2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f, -1.0925484305920792f,
                       0.5462742152960396f};
  const float C3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f, 0.3731763325901154f,
                       -0.4570457994644658f, 1.445305721320277f, -0.5900435899266435f};
  at::parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const float x = dp[3 * i], y = dp[3 * i + 1], z = dp[3 * i + 2];
      float* r = op + i * ld + col;
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
  });
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

// out[:, :N_last] = MLP(x) for torch.nn.Linear weights [N_i, K_i] and biases [N_i], ReLU between layers.
void mlp_forward(const at::Tensor& x, const std::vector<at::Tensor>& weights, const std::vector<at::Tensor>& biases,
                 at::Tensor out) {
  TORCH_CHECK(x.device().is_cpu() && x.scalar_type() == at::kFloat && x.dim() == 2 && x.stride(1) == 1,
              "mlp_forward: x must be a float32 CPU matrix with unit column stride");
  TORCH_CHECK(!weights.empty() && weights.size() == biases.size(), "mlp_forward: one bias per weight");
  const int64_t n = x.size(0);
  std::vector<Layer> layers(weights.size());
  int64_t k = x.size(1), widest = k;
  for (size_t l = 0; l < weights.size(); ++l) {
    const at::Tensor w = weights[l].contiguous(), b = biases[l].contiguous();
    TORCH_CHECK(w.scalar_type() == at::kFloat && w.dim() == 2 && w.size(1) == k && b.numel() == w.size(0),
                "mlp_forward: layer ", l, " does not fit its input");
    Layer& L = layers[l];
    L.k = k;
    L.n = w.size(0);
    L.npad = (L.n + 15) / 16 * 16;
    L.w.assign(L.k * L.npad, 0.f);
    L.b.assign(L.npad, 0.f);
    const float* wp = w.data_ptr<float>();
    for (int64_t o = 0; o < L.n; ++o)
      for (int64_t i = 0; i < L.k; ++i) L.w[i * L.npad + o] = wp[o * L.k + i];
    for (int64_t o = 0; o < L.n; ++o) L.b[o] = b.data_ptr<float>()[o];
    k = L.n;
    widest = std::max(widest, L.npad);
  }
  TORCH_CHECK(out.device().is_cpu() && out.scalar_type() == at::kFloat && out.dim() == 2 && out.size(0) == n &&
                  out.size(1) >= layers.back().n && out.stride(1) == 1,
              "mlp_forward: out must be a float32 CPU matrix [N, >= ", layers.back().n, "] with unit column stride");
  const float* xp = x.data_ptr<float>();
  const int64_t ldx = x.stride(0);
  float* op = out.data_ptr<float>();
  const int64_t ldo = out.stride(0);
  const int64_t n_last = layers.back().n;
  at::parallel_for(0, (n + kRows - 1) / kRows, 64, [&](int64_t begin, int64_t end) {
    std::vector<float> a(kRows * widest, 0.f), b(kRows * widest, 0.f);
    for (int64_t blk = begin; blk < end; ++blk) {
      const int64_t r0 = blk * kRows;
      const int64_t rows = std::min<int64_t>(kRows, n - r0);
      // Input rows (a partial last block repeats its last row; only `rows` rows are written back).
      for (int r = 0; r < kRows; ++r) {
        const float* src = xp + (r0 + std::min<int64_t>(r, rows - 1)) * ldx;
        std::copy(src, src + layers[0].k, a.data() + r * widest);
      }
      float* cur = a.data();
      float* nxt = b.data();
      for (size_t l = 0; l < layers.size(); ++l) {
        layer_block(layers[l], cur, widest, nxt, widest, l + 1 < layers.size());
        std::swap(cur, nxt);
      }
      for (int64_t r = 0; r < rows; ++r) std::copy(cur + r * widest, cur + r * widest + n_last, op + (r0 + r) * ldo);
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
}
