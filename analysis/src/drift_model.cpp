// Drift model (paper eq. 1): spec parsing, smoothing derivative, and the
// least-squares fit (Gram path or block-sequential Householder QR); see
// drift_model.h.
#include "gyrotherm/analysis/drift_model.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <thread>

#include "common.h"
#include "compensated_sum.h"
#include "target_clones.h"

namespace gyrotherm::analysis {
namespace {

constexpr double kWindowTol = 1e-9;  // relative to the derivative half width
// A variable is "constant" when its std is below this times its size.
constexpr double kConstantTol = 1e-10;
// Rows per block of the streamed passes (derivative, design rows, Gram).
constexpr std::size_t kRowBlock = 256;
// The Gram (normal-equations) path is used only when the column-scaled
// design's condition number is at most this; see drift_model.h.
constexpr double kGramMaxCondition = 100.0;
// ... and RSS is recomputed from the residuals when RSS < this x y'y.
constexpr double kGramMinRssFraction = 1e-4;

std::string_view trim_spaces(std::string_view s) {
  while (!s.empty() && s.front() == ' ') s.remove_prefix(1);
  while (!s.empty() && s.back() == ' ') s.remove_suffix(1);
  return s;
}

// Least-squares slope at each point over a window of points around it, in
// O(1) amortised per point, computed block by block (blocks must follow each
// other: i0 = 0, then the end of the previous block, ...). Sums of
// t - t_ref, y - y_ref and their products are kept relative to an anchor
// point; the anchor moves (and the sums are recomputed from scratch) once the
// point has moved max(16, 2 x window points) past it, so the sums never hold
// large offsets and the double rounding stays ~1e-13 relative. A block is
// cut into kLanes stretches whose add chains run interleaved.
template <class YAt>
class DerivativeStream {
 public:
  static constexpr std::size_t kLanes = 4;

  DerivativeStream(std::span<const double> t_s, YAt y_at, double window_s)
      : t_(t_s), y_at_(y_at), half_(window_s / 2), tol_(kWindowTol * window_s / 2) {}

  // Start the stream at point i instead of 0 (before the first next_block).
  void start_at(std::size_t i) {
    if (i == 0 || t_.empty()) return;
    const double bound = t_[i] - half_ - tol_;
    lo_ptr_ = static_cast<std::size_t>(std::lower_bound(t_.begin(), t_.end(), bound) - t_.begin());
    lo_ptr_ = std::min(lo_ptr_, i);
    hi_ptr_ = i;
  }

  // Derivative at points i0 .. i0 + count - 1 into out[0 .. count).
  void next_block(std::size_t i0, std::size_t count, double* out) {
    const std::size_t n = t_.size();
    if (n < 2) {
      std::fill(out, out + count, kNaN);
      return;
    }
    if (uniform_block(i0, count, out)) return;
    lo_.resize(count);
    hi_.resize(count);
    for (std::size_t k = 0; k < count; ++k) {
      const std::size_t i = i0 + k;
      while (t_[lo_ptr_] < t_[i] - half_ - tol_) ++lo_ptr_;
      if (hi_ptr_ < i) hi_ptr_ = i;
      while (hi_ptr_ + 1 < n && t_[hi_ptr_ + 1] <= t_[i] + half_ + tol_) ++hi_ptr_;
      lo_[k] = i > 0 ? std::min(lo_ptr_, i - 1) : lo_ptr_;
      hi_[k] = i + 1 < n ? std::max(hi_ptr_, i + 1) : hi_ptr_;
    }
    const std::size_t len = (count + kLanes - 1) / kLanes;
    Lane lanes[kLanes];
    for (std::size_t step = 0; step < len; ++step) {
      for (std::size_t l = 0; l < kLanes; ++l) {
        const std::size_t k = l * len + step;
        if (k >= count) continue;
        Lane& ln = lanes[l];
        const std::size_t i = i0 + k;
        if (step == 0 || i - ln.anchor >= ln.reanchor) {
          fresh(ln, i, lo_[k], hi_[k]);
        } else {
          for (std::size_t j = ln.hi + 1; j <= hi_[k]; ++j) add(ln, j, +1.0);
          for (std::size_t j = ln.lo; j < lo_[k]; ++j) add(ln, j, -1.0);
          ln.lo = lo_[k];
          ln.hi = hi_[k];
        }
        const double m = static_cast<double>(ln.hi - ln.lo + 1);
        const double sxx = ln.s_tt - ln.s_t * ln.s_t / m;
        const double sxy = ln.s_ty - ln.s_t * ln.s_y / m;
        out[k] = sxy / sxx;
      }
    }
  }

 private:
  // Evenly spaced stretch (every t_{j+1} - t_j over the block's windows equal
  // to the same dt, so t_{i+k} - t_i = k dt exactly) and every point with the
  // same symmetric window i - h .. i + h: the slope is then the fixed kernel
  //   sum_{k=1..h} k (y_{i+k} - y_{i-k}) / (dt sum_{k=-h..h} k^2),
  // the same least-squares slope without the sliding sums. False (nothing
  // written) when the block does not qualify.
  bool uniform_block(std::size_t i0, std::size_t count, double* out) {
    const std::size_t n = t_.size();
    // The window of the first point by the general rule gives h.
    while (t_[lo_ptr_] < t_[i0] - half_ - tol_) ++lo_ptr_;
    if (hi_ptr_ < i0) hi_ptr_ = i0;
    while (hi_ptr_ + 1 < n && t_[hi_ptr_ + 1] <= t_[i0] + half_ + tol_) ++hi_ptr_;
    const std::size_t h = hi_ptr_ - i0;
    const std::size_t last = i0 + count - 1;
    if (h == 0 || i0 - lo_ptr_ != h || i0 < h + 1 || last + h + 1 >= n) return false;
    // Every point's window is i - h .. i + h by the same rule (checked for all
    // points at once, without branches), and the spacing is exactly uniform.
    const std::size_t j0 = i0 - h, j1 = last + h;
    const double dt = t_[j0 + 1] - t_[j0];
    const double* t = t_.data();
    const double half = half_, tol = tol_;  // the same sums as the general rule
    // Branch-free and bitwise, so the loops vectorise.
    std::int64_t ok = 1;
    for (std::size_t i = i0; i <= last; ++i) {
      const double up = t[i] + half + tol;
      const double dn = t[i] - half - tol;
      ok &=
          static_cast<std::int64_t>(t[i + h] <= up) & static_cast<std::int64_t>(t[i + h + 1] > up) &
          static_cast<std::int64_t>(t[i - h] >= dn) & static_cast<std::int64_t>(t[i - h - 1] < dn);
    }
    for (std::size_t j = j0; j < j1; ++j) ok &= static_cast<std::int64_t>((t[j + 1] - t[j]) == dt);
    if (ok == 0 || !(dt > 0)) return false;
    lo_ptr_ = last - h;
    hi_ptr_ = last + h;
    ybuf_.resize(j1 - j0 + 1);
    const double y_ref = y_at_(i0);
    for (std::size_t j = j0; j <= j1; ++j) ybuf_[j - j0] = y_at_(j) - y_ref;
    const double* y = ybuf_.data() + h;  // y[k] is point i0 + k (k from -h)
    // Window sum W_i and moment N_i = sum_k k y_{i+k} slide together:
    //   W_{i+1} = W_i + y_{i+h+1} - y_{i-h},
    //   N_{i+1} = N_i + h y_{i-h} + (h + 1) y_{i+h+1} - W_{i+1};
    // kLanes stretches run interleaved, each from fresh sums.
    const auto hs = static_cast<std::ptrdiff_t>(h);
    const double hd = static_cast<double>(h);
    const double inv = 1.0 / (dt * (hd * (hd + 1) * (2 * hd + 1) / 3));
    const std::size_t len = (count + kLanes - 1) / kLanes;
    double w[kLanes], m[kLanes];
    std::size_t end[kLanes];
    for (std::size_t l = 0; l < kLanes; ++l) {
      const std::size_t start = std::min(l * len, count);
      end[l] = std::min(start + len, count);
      double sw = 0, sm = 0;
      if (start < end[l]) {
        for (std::ptrdiff_t k = -hs; k <= hs; ++k) {
          const double v = y[static_cast<std::ptrdiff_t>(start) + k];
          sw += v;
          sm += static_cast<double>(k) * v;
        }
      }
      w[l] = sw;
      m[l] = sm;
    }
    for (std::size_t step = 0; step < len; ++step) {
      for (std::size_t l = 0; l < kLanes; ++l) {
        const std::size_t i = l * len + step;
        if (i >= end[l]) continue;
        out[i] = m[l] * inv;
        if (i + 1 == end[l]) continue;
        const auto ii = static_cast<std::ptrdiff_t>(i);
        const double y_old = y[ii - hs];
        const double y_new = y[ii + hs + 1];
        w[l] += y_new - y_old;
        m[l] += (hd * y_old + (hd + 1) * y_new) - w[l];
      }
    }
    return true;
  }

  struct Lane {
    std::size_t lo = 0, hi = 0, anchor = 0, reanchor = 16;
    double t_ref = 0, y_ref = 0;
    double s_t = 0, s_y = 0, s_tt = 0, s_ty = 0;
  };
  void fresh(Lane& ln, std::size_t i, std::size_t lo, std::size_t hi) {
    ln.anchor = i;
    ln.reanchor = std::max<std::size_t>(16, 2 * (hi - lo + 1));
    ln.t_ref = t_[i];
    ln.y_ref = y_at_(i);
    ln.s_t = ln.s_y = ln.s_tt = ln.s_ty = 0;
    ln.lo = lo;
    ln.hi = hi;
    for (std::size_t j = lo; j <= hi; ++j) add(ln, j, +1.0);
  }
  void add(Lane& ln, std::size_t j, double sign) {
    const double dt = t_[j] - ln.t_ref;
    const double dy = y_at_(j) - ln.y_ref;
    ln.s_t += sign * dt;
    ln.s_y += sign * dy;
    ln.s_tt += sign * (dt * dt);
    ln.s_ty += sign * (dt * dy);
  }

  std::span<const double> t_;
  YAt y_at_;
  double half_, tol_;
  std::size_t lo_ptr_ = 0, hi_ptr_ = 0;
  std::vector<std::size_t> lo_, hi_;
  std::vector<double> ybuf_;
};

struct ShellTemp {
  const AnalysisSeries* s;
  double operator()(std::size_t i) const { return (s->top_c[i] + s->side_c[i]) / 2; }
};

using Lanes = double __attribute__((vector_size(16)));

// Mean, population std and largest |x| of a variable, from sums of x - shift
// (shift: the first value seen, so a constant variable gives exactly 0). Used
// only to centre and scale the design and to detect a constant variable.
struct ShiftedStats {
  bool started = false;
  double shift = 0, sum = 0, sum2 = 0, max_abs = 0;
  std::size_t n = 0;
  void add_block(const double* x, std::size_t count) {
    if (count == 0) return;
    if (!started) {
      shift = x[0];
      started = true;
    }
    // Four interleaved partial sums (two SSE2 pairs), so the add chains run
    // in parallel.
    Lanes a0{}, a1{}, q0{}, q1{}, m0{max_abs, max_abs}, m1 = m0;
    const std::size_t count4 = count / 4 * 4;
    for (std::size_t i = 0; i < count4; i += 4) {
      Lanes v0, v1;
      std::memcpy(&v0, x + i, sizeof v0);
      std::memcpy(&v1, x + i + 2, sizeof v1);
      const Lanes d0 = v0 - shift, d1 = v1 - shift;
      a0 += d0;
      a1 += d1;
      q0 += d0 * d0;
      q1 += d1 * d1;
      const Lanes b0 = v0 < 0 ? -v0 : v0, b1 = v1 < 0 ? -v1 : v1;
      m0 = m0 > b0 ? m0 : b0;
      m1 = m1 > b1 ? m1 : b1;
    }
    for (std::size_t i = count4; i < count; ++i) {
      const double d = x[i] - shift;
      a0[0] += d;
      q0[0] += d * d;
      m0[0] = std::max(m0[0], std::abs(x[i]));
    }
    sum += (a0[0] + a0[1]) + (a1[0] + a1[1]);
    sum2 += (q0[0] + q0[1]) + (q1[0] + q1[1]);
    const Lanes mx = m0 > m1 ? m0 : m1;
    max_abs = std::max(mx[0], mx[1]);
    n += count;
  }
  void merge(const ShiftedStats& o) {
    if (!o.started) return;
    if (!started) {
      *this = o;
      return;
    }
    const double d = o.shift - shift;
    const double no = static_cast<double>(o.n);
    sum2 += o.sum2 + 2 * d * o.sum + no * d * d;
    sum += o.sum + no * d;
    max_abs = std::max(max_abs, o.max_abs);
    n += o.n;
  }
  double mean() const { return n > 0 ? shift + sum / static_cast<double>(n) : 0; }
  double std_ddof0() const {
    if (n == 0) return 0;
    const double nd = static_cast<double>(n);
    return std::sqrt(std::max(0.0, sum2 / nd - (sum / nd) * (sum / nd)));
  }
};

// body(states[0], 0, n), or for a long series body(states[0], 0, mid) and
// body(states[1], mid, n) on two threads (mid on a block boundary). Every sum
// is compensated, so the result depends on the split only by rounding.
constexpr std::size_t kParallelRows = std::size_t{1} << 18;
template <class State, class Body>
void over_halves(std::size_t n, State* states, Body&& body) {
  if (n < kParallelRows) {
    body(states[0], std::size_t{0}, n);
    return;
  }
  const std::size_t mid = n / 2 / kRowBlock * kRowBlock;
  std::thread other([&] { body(states[1], mid, n); });
  body(states[0], std::size_t{0}, mid);
  other.join();
}

Status check_series_named(const AnalysisSeries& s, std::string_view what) {
  const std::size_t n = s.t_s.size();
  if (s.rate_dph.size() != n || s.top_c.size() != n || s.side_c.size() != n) {
    return Error::Permanent(fmt::format(
        "{}: series vectors differ in length (t_s {}, rate_dph {}, top_c {}, side_c {})", what, n,
        s.rate_dph.size(), s.top_c.size(), s.side_c.size()));
  }
  // Fast screen (branch-free, vectorised): x * 0 is NaN exactly for a NaN or
  // infinite x; the exact search below runs only when the screen finds
  // something.
  const double* t = s.t_s.data();
  const double* rate = s.rate_dph.data();
  const double* top = s.top_c.data();
  const double* side = s.side_c.data();
  std::uint64_t bad_part[2] = {0, 0};
  over_halves(n, bad_part, [&](std::uint64_t& bad, std::size_t begin, std::size_t end) {
    std::uint64_t b = 0;
    for (std::size_t i = std::max<std::size_t>(begin, 1); i < end; ++i) {
      const double zero = t[i] * 0.0 + rate[i] * 0.0 + top[i] * 0.0 + side[i] * 0.0;
      b |=
          static_cast<std::uint64_t>(!(zero == 0)) | static_cast<std::uint64_t>(!(t[i] > t[i - 1]));
    }
    bad = b;
  });
  std::uint64_t bad = bad_part[0] | bad_part[1];
  if (n > 0) {
    bad |= static_cast<std::uint64_t>(
        !(t[0] * 0.0 + rate[0] * 0.0 + top[0] * 0.0 + side[0] * 0.0 == 0));
  }
  if (bad == 0) return Status::Ok();
  const std::array<std::pair<const char*, const std::vector<double>*>, 4> vecs = {
      {{"t_s", &s.t_s}, {"rate_dph", &s.rate_dph}, {"top_c", &s.top_c}, {"side_c", &s.side_c}}};
  for (std::size_t i = 0; i < n; ++i) {
    for (const auto& [name, v] : vecs) {
      if (!std::isfinite((*v)[i])) {
        return Error::Permanent(
            fmt::format("{}: {}[{}] is not finite ({})", what, name, i, (*v)[i]));
      }
    }
    if (i > 0 && !(s.t_s[i] > s.t_s[i - 1])) {
      return Error::Permanent(fmt::format("{}: t_s[{}]={} does not increase (t_s[{}]={})", what, i,
                                          s.t_s[i], i - 1, s.t_s[i - 1]));
    }
  }
  return Status::Ok();
}

struct Column {
  char var;   // 'T', 'R', 'G', or 'C' for the intercept
  int power;  // 0 for the intercept
};

std::vector<Column> design_columns(const DriftModelSpec& spec, DriftModelForm form) {
  std::vector<Column> cols;
  if (form == DriftModelForm::kCentered) cols.push_back({'C', 0});
  for (int i = 1; i <= spec.t_order; ++i) cols.push_back({'T', i});
  for (int i = 1; i <= spec.r_order; ++i) cols.push_back({'R', i});
  for (int i = 1; i <= spec.g_order; ++i) cols.push_back({'G', i});
  return cols;
}

std::string column_name(const Column& c) {
  return c.var == 'C' ? std::string("intercept") : fmt::format("{}{}", c.var, c.power);
}

double ipow(double x, int k) {
  double r = 1;
  for (int i = 0; i < k; ++i) r *= x;
  return r;
}

double binomial(int n, int k) {
  double r = 1;
  for (int i = 1; i <= k; ++i) r = r * (n - k + i) / i;
  return r;
}

// Scaled variables of one point: z = (x - center) / scale.
struct Scaling {
  double t_center, t_scale, r_center, r_scale, g_center, g_scale;
};

void fill_row(const std::vector<Column>& cols, const Scaling& sc, double temp, double rate,
              double grad, double* row) {
  const double zt = (temp - sc.t_center) / sc.t_scale;
  const double zr = (rate - sc.r_center) / sc.r_scale;
  const double zg = (grad - sc.g_center) / sc.g_scale;
  for (std::size_t c = 0; c < cols.size(); ++c) {
    const double z = cols[c].var == 'T' ? zt : cols[c].var == 'R' ? zr : zg;
    row[c] = cols[c].var == 'C' ? 1.0 : ipow(z, cols[c].power);
  }
}

}  // namespace

Result<DriftModelSpec> parse_model_spec(std::string_view s) {
  if (trim_spaces(s).empty()) return Error::Permanent("model spec is empty (e.g. \"T4+R1+G1\")");
  DriftModelSpec spec;
  bool seen[3] = {false, false, false};
  std::string_view rest = s;
  while (true) {
    const std::size_t plus = rest.find('+');
    const std::string_view term = trim_spaces(rest.substr(0, plus));
    if (term.empty()) {
      return Error::Permanent(fmt::format("model spec \"{}\": empty term", s));
    }
    const char letter = term[0];
    int slot = letter == 'T' ? 0 : letter == 'R' ? 1 : letter == 'G' ? 2 : -1;
    if (slot < 0) {
      return Error::Permanent(fmt::format("{}: unknown term (T, R, G)", term));
    }
    if (term.size() != 2 || term[1] < '0' || term[1] > '9' || term[1] - '0' > kMaxTermOrder) {
      return Error::Permanent(fmt::format("{}: order must be 0..{}", term, kMaxTermOrder));
    }
    if (seen[slot]) {
      return Error::Permanent(fmt::format("{}: term {} given more than once", term, letter));
    }
    seen[slot] = true;
    const int order = term[1] - '0';
    (slot == 0 ? spec.t_order : slot == 1 ? spec.r_order : spec.g_order) = order;
    if (plus == std::string_view::npos) break;
    rest = rest.substr(plus + 1);
  }
  if (spec.parameters() == 0) {
    return Error::Permanent(fmt::format("model spec \"{}\" has no term of order >= 1", s));
  }
  return spec;
}

std::string to_string(const DriftModelSpec& spec) {
  std::string out;
  const auto add = [&out](char letter, int order) {
    if (order == 0) return;
    if (!out.empty()) out += '+';
    out += fmt::format("{}{}", letter, order);
  };
  add('T', spec.t_order);
  add('R', spec.r_order);
  add('G', spec.g_order);
  return out;
}

std::string_view to_string(DriftModelForm form) {
  return form == DriftModelForm::kPaper ? "paper" : "centered";
}

Result<DriftModelForm> parse_drift_model_form(std::string_view s) {
  if (s == "paper") return DriftModelForm::kPaper;
  if (s == "centered" || s == "centred") return DriftModelForm::kCentered;
  return Error::Permanent(fmt::format("drift model form \"{}\": expected paper or centered", s));
}

bool DriftFitOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  if (!(derivative_window_s > 0) || !std::isfinite(derivative_window_s)) {
    return fail(fmt::format("derivative_window_s must be positive ({})", derivative_window_s));
  }
  if (!(l0_window_s > 0) || !std::isfinite(l0_window_s)) {
    return fail(fmt::format("l0_window_s must be positive ({})", l0_window_s));
  }
  if (block_rows == 0) return fail("block_rows must be at least 1");
  if (!(rank_tolerance >= 0 && rank_tolerance < 1)) {
    return fail(fmt::format("rank_tolerance must be in [0, 1) ({})", rank_tolerance));
  }
  return true;
}

std::vector<double> smoothing_derivative(std::span<const double> t_s, std::span<const double> y,
                                         double window_s) {
  std::vector<double> out(t_s.size(), kNaN);
  if (t_s.size() != y.size() || t_s.size() < 2 || !(window_s > 0)) return out;
  const auto y_at = [y](std::size_t j) { return y[j]; };
  DerivativeStream<decltype(y_at)> slope(t_s, y_at, window_s);
  for (std::size_t i = 0; i < t_s.size(); i += kRowBlock) {
    slope.next_block(i, std::min(kRowBlock, t_s.size() - i), out.data() + i);
  }
  return out;
}

Result<DriftFit> fit_drift_model(const AnalysisSeries& series, const DriftModelSpec& spec,
                                 DriftModelForm form, const DriftFitOptions& options) {
  return fit_drift_model(std::span<const AnalysisSeries>(&series, 1), spec, form, options);
}

namespace {

// Streams one series in blocks of kRowBlock points: the mean shell
// temperature, its smoothing derivative and the gradient top - side of each
// point, handed to fn(i0, count, temp, deriv, grad).
template <class Fn>
void for_each_block(const AnalysisSeries& series, double window_s, Fn&& fn, std::size_t begin = 0,
                    std::size_t end = SIZE_MAX) {
  const ShellTemp temp_at{&series};
  DerivativeStream<ShellTemp> slope(series.t_s, temp_at, window_s);
  slope.start_at(begin);
  double temp[kRowBlock], deriv[kRowBlock], grad[kRowBlock];
  const std::size_t n = std::min(end, series.t_s.size());
  for (std::size_t i0 = begin; i0 < n; i0 += kRowBlock) {
    const std::size_t count = std::min(kRowBlock, n - i0);
    slope.next_block(i0, count, deriv);
    for (std::size_t k = 0; k < count; ++k) {
      temp[k] = (series.top_c[i0 + k] + series.side_c[i0 + k]) / 2;
      grad[k] = series.top_c[i0 + k] - series.side_c[i0 + k];
    }
    fn(i0, count, temp, deriv, grad);
  }
}

// The design columns of a block, column-major with stride kRowBlock: column c
// of row k at cols[c * kRowBlock + k]. Rows past count are left as they are.
void fill_columns(const std::vector<Column>& cols, const Scaling& sc, std::size_t count,
                  const double* temp, const double* deriv, const double* grad, double* out) {
  for (std::size_t c = 0; c < cols.size(); ++c) {
    double* col = out + c * kRowBlock;
    const Column& cd = cols[c];
    if (cd.var == 'C') {
      std::fill(col, col + count, 1.0);
    } else if (cd.power > 1) {
      const double* prev = col - kRowBlock;  // the same variable, one power lower
      const double* z = out + (c - static_cast<std::size_t>(cd.power - 1)) * kRowBlock;
      for (std::size_t k = 0; k < count; ++k) col[k] = prev[k] * z[k];
    } else {
      const double* x = cd.var == 'T' ? temp : cd.var == 'R' ? deriv : grad;
      const double center = cd.var == 'T' ? sc.t_center : cd.var == 'R' ? sc.r_center : sc.g_center;
      const double scale = cd.var == 'T' ? sc.t_scale : cd.var == 'R' ? sc.r_scale : sc.g_scale;
      // A power-of-two scale (the provisional ones) divides exactly by a product.
      int exponent = 0;
      if (const double inverse = 1 / scale;
          std::frexp(scale, &exponent) == 0.5 && std::isfinite(inverse)) {
        for (std::size_t k = 0; k < count; ++k) col[k] = (x[k] - center) * inverse;
      } else {
        for (std::size_t k = 0; k < count; ++k) col[k] = (x[k] - center) / scale;
      }
    }
  }
}

using Vec4 = double __attribute__((vector_size(32)));

// G[a][b] += column a . column b for a <= b < q (g with row stride q4, x
// with q4 columns, those past q zero; entries with b >= q are not computed).
GYROTHERM_AVX2_CLONES void gram_accumulate(const double* x, std::size_t q, std::size_t rows4,
                                           double* g) {
  const std::size_t q4 = (q + 3) / 4 * 4;
  for (std::size_t a0 = 0; a0 < q4; a0 += 4) {
    const double* xa = x + a0 * kRowBlock;
    for (std::size_t b = a0; b < q; ++b) {
      const double* xb = x + b * kRowBlock;
      Vec4 acc0 = {0, 0, 0, 0}, acc1 = acc0, acc2 = acc0, acc3 = acc0;
      Vec4 vb, v0, v1, v2, v3;
      for (std::size_t i = 0; i < rows4; i += 4) {
        std::memcpy(&vb, xb + i, sizeof vb);
        std::memcpy(&v0, xa + i, sizeof vb);
        std::memcpy(&v1, xa + kRowBlock + i, sizeof vb);
        std::memcpy(&v2, xa + 2 * kRowBlock + i, sizeof vb);
        std::memcpy(&v3, xa + 3 * kRowBlock + i, sizeof vb);
        acc0 += v0 * vb;
        acc1 += v1 * vb;
        acc2 += v2 * vb;
        acc3 += v3 * vb;
      }
      const Vec4* accs[4] = {&acc0, &acc1, &acc2, &acc3};
      for (std::size_t k = 0; k < 4; ++k) {
        const Vec4& v = *accs[k];
        g[(a0 + k) * q4 + b] += (v[0] + v[1]) + (v[2] + v[3]);
      }
    }
  }
}

// What a solver hands to the common tail: the p x p triangular factor R of
// the scaled design, Q'y and the residual sum of squares.
struct Factor {
  Eigen::MatrixXd rx;
  Eigen::VectorXd qty;
  double rss = 0;
  std::string solver;
};

// Householder path: R of [X | y] by QR of [R; next block], block by block.
Factor householder_factor(std::span<const AnalysisSeries> runs, const std::vector<Column>& cols,
                          const Scaling& sc, const std::vector<double>& l0,
                          const DriftFitOptions& options) {
  const std::size_t p = cols.size();
  const std::size_t q = p + 1;
  const std::size_t block = options.block_rows;
  Eigen::MatrixXd stack =
      Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(q + block), static_cast<Eigen::Index>(q));
  Eigen::HouseholderQR<Eigen::MatrixXd> qr(stack.rows(), stack.cols());
  Eigen::MatrixXd r_aug =
      Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(q), static_cast<Eigen::Index>(q));
  std::vector<double> row(p);
  std::size_t filled = 0;  // rows of the current block
  const auto flush_block = [&] {
    qr.compute(stack.topRows(static_cast<Eigen::Index>(q + filled)));
    r_aug = qr.matrixQR().topRows(static_cast<Eigen::Index>(q)).triangularView<Eigen::Upper>();
    stack.topRows(static_cast<Eigen::Index>(q)) = r_aug;
    filled = 0;
  };
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const AnalysisSeries& series = runs[r];
    for_each_block(series, options.derivative_window_s,
                   [&](std::size_t i0, std::size_t count, const double* temp, const double* deriv,
                       const double* grad) {
                     for (std::size_t k = 0; k < count; ++k) {
                       fill_row(cols, sc, temp[k], deriv[k], grad[k], row.data());
                       const auto at = static_cast<Eigen::Index>(q + filled);
                       for (std::size_t c = 0; c < p; ++c) {
                         stack(at, static_cast<Eigen::Index>(c)) = row[c];
                       }
                       stack(at, static_cast<Eigen::Index>(p)) = series.rate_dph[i0 + k] - l0[r];
                       if (++filled == block) flush_block();
                     }
                   });
  }
  if (filled > 0) flush_block();
  const auto ip = static_cast<Eigen::Index>(p);
  Factor f;
  f.rx = r_aug.topLeftCorner(ip, ip);
  f.qty = r_aug.topRightCorner(ip, 1);
  f.rss = r_aug(ip, ip) * r_aug(ip, ip);
  f.solver = "householder";
  return f;
}

// The Gram matrix is accumulated in the same pass as the statistics that
// centre and scale the variables, so in provisional variables: centres and
// scales from a strided sample of about kSampleRows points (dT/dt there by a
// difference over the derivative window). It is then mapped exactly to the
// documented variables (basis_map), which is accurate only when the two are
// close: every centre within kMaxCenterShift exact stds of the exact one
// (y's too), every scale within a factor kMaxScaleRatio. Otherwise the Gram
// matrix is accumulated again in the exact variables.
constexpr std::size_t kSampleRows = 4096;
constexpr double kMaxCenterShift = 0.25;
constexpr double kMaxScaleRatio = 1e4;

struct Provisional {
  Scaling sc{0, 1, 0, 1, 0, 1};
  double y_center = 0;
};

// Rough dT/dt at point i: the slope between the ends of its window (the
// window found as in DerivativeStream, by galloping from i).
double rough_derivative(const AnalysisSeries& s, std::size_t i, double half) {
  const std::vector<double>& t = s.t_s;
  const std::size_t n = t.size();
  const auto at = [&t](std::size_t j) { return t.begin() + static_cast<std::ptrdiff_t>(j); };
  std::size_t step = 1;
  while (step <= i && t[i - step] >= t[i] - half) step *= 2;
  std::size_t lo = static_cast<std::size_t>(
      std::lower_bound(at(step <= i ? i - step : 0), at(i + 1), t[i] - half) - t.begin());
  step = 1;
  while (i + step < n && t[i + step] <= t[i] + half) step *= 2;
  std::size_t hi = static_cast<std::size_t>(
      std::upper_bound(at(i), at(std::min(n - 1, i + step) + 1), t[i] + half) - t.begin() - 1);
  if (i > 0) lo = std::min(lo, i - 1);
  if (i + 1 < n) hi = std::max(hi, i + 1);
  const ShellTemp temp{&s};
  return (temp(hi) - temp(lo)) / (t[hi] - t[lo]);
}

Provisional provisional_scaling(std::span<const AnalysisSeries> runs, const std::vector<double>& l0,
                                DriftModelForm form, double window_s) {
  std::size_t n = 0;
  for (const AnalysisSeries& s : runs) n += s.t_s.size();
  const std::size_t stride = std::max<std::size_t>(1, n / kSampleRows);
  std::array<std::vector<double>, 4> v;  // T, dT/dt, dT, y
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const AnalysisSeries& s = runs[r];
    for (std::size_t i = 0; i < s.t_s.size(); i += stride) {
      v[0].push_back((s.top_c[i] + s.side_c[i]) / 2);
      v[1].push_back(rough_derivative(s, i, window_s / 2));
      v[2].push_back(s.top_c[i] - s.side_c[i]);
      v[3].push_back(s.rate_dph[i] - l0[r]);
    }
  }
  std::array<double, 4> center{}, scale{};
  for (std::size_t k = 0; k < 4; ++k) {
    const double m = static_cast<double>(v[k].size());
    double mean = 0, ss = 0, max_abs = 0;
    for (double x : v[k]) mean += x;
    mean /= m;
    for (double x : v[k]) {
      ss += (x - mean) * (x - mean);
      max_abs = std::max(max_abs, std::abs(x));
    }
    center[k] = form == DriftModelForm::kPaper ? 0.0 : mean;
    scale[k] = form == DriftModelForm::kPaper ? max_abs : std::sqrt(ss / m);
    if (!(scale[k] > 0) || !std::isfinite(scale[k])) scale[k] = 1;
    scale[k] = std::exp2(std::round(std::log2(scale[k])));  // exact to divide by
    if (!(scale[k] > 0) || !std::isfinite(scale[k])) scale[k] = 1;
    if (!std::isfinite(center[k])) center[k] = 0;
  }
  Provisional out;
  out.sc = {center[0], scale[0], center[1], scale[1], center[2], scale[2]};
  out.y_center = form == DriftModelForm::kCentered ? center[3] : 0.0;
  return out;
}

// The single pass: L0-relative y, the statistics of T, dT/dt, dT and y (exact,
// as documented) and, when `gram`, the Gram matrix of [X | y - y_center] with
// X in the variables of sc (compensated across blocks; q x q, q = p + 1).
struct PassResult {
  ShiftedStats ts, rs, gs, ys;
  double max_side_top = 0;
  Eigen::MatrixXd gram;
};

PassResult stats_and_gram(std::span<const AnalysisSeries> runs, const std::vector<Column>& cols,
                          const Scaling& sc, double y_center, const std::vector<double>& l0,
                          double window_s, bool gram) {
  const std::size_t p = cols.size();
  const std::size_t q = p + 1;
  const std::size_t q4 = (q + 3) / 4 * 4;
  struct alignas(64) State {  // no false sharing between the two threads
    ShiftedStats ts, rs, gs, ys;
    double max_side_top = 0;
    std::vector<double> x, g_block;
    std::vector<CompensatedSum> g_total;
  };
  State states[2];
  for (State& st : states) {
    st.x.assign(q4 * kRowBlock, 0.0);
    st.g_block.resize(q4 * q4);
    st.g_total.resize(q4 * q4);
  }
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const AnalysisSeries& series = runs[r];
    over_halves(series.t_s.size(), states, [&](State& st, std::size_t begin, std::size_t end) {
      for_each_block(
          series, window_s,
          [&](std::size_t i0, std::size_t count, const double* temp, const double* deriv,
              const double* grad) {
            st.ts.add_block(temp, count);
            st.rs.add_block(deriv, count);
            st.gs.add_block(grad, count);
            double* y = st.x.data() + p * kRowBlock;
            const double* top = series.top_c.data() + i0;
            const double* side = series.side_c.data() + i0;
            const double* rate = series.rate_dph.data() + i0;
            const double l0r = l0[r];
            for (std::size_t k = 0; k < count; ++k) y[k] = rate[k] - l0r;
            double mx0 = st.max_side_top, mx1 = mx0, mx2 = mx0, mx3 = mx0;
            const std::size_t count4 = count / 4 * 4;
            for (std::size_t k = 0; k < count4; k += 4) {
              mx0 = std::max(mx0, std::max(std::abs(top[k]), std::abs(side[k])));
              mx1 = std::max(mx1, std::max(std::abs(top[k + 1]), std::abs(side[k + 1])));
              mx2 = std::max(mx2, std::max(std::abs(top[k + 2]), std::abs(side[k + 2])));
              mx3 = std::max(mx3, std::max(std::abs(top[k + 3]), std::abs(side[k + 3])));
            }
            for (std::size_t k = count4; k < count; ++k) {
              mx0 = std::max(mx0, std::max(std::abs(top[k]), std::abs(side[k])));
            }
            st.max_side_top = std::max(std::max(mx0, mx1), std::max(mx2, mx3));
            st.ys.add_block(y, count);
            if (!gram) return;
            for (std::size_t k = 0; k < count; ++k) y[k] -= y_center;
            fill_columns(cols, sc, count, temp, deriv, grad, st.x.data());
            const std::size_t rows4 = (count + 3) / 4 * 4;
            if (rows4 != count) {
              for (std::size_t c = 0; c < q; ++c) {
                std::fill(st.x.data() + c * kRowBlock + count, st.x.data() + c * kRowBlock + rows4,
                          0.0);
              }
            }
            std::fill(st.g_block.begin(), st.g_block.end(), 0.0);
            gram_accumulate(st.x.data(), q, rows4, st.g_block.data());
            for (std::size_t i = 0; i < q; ++i) {
              for (std::size_t j = i; j < q; ++j)
                st.g_total[i * q4 + j].add(st.g_block[i * q4 + j]);
            }
          },
          begin, end);
    });
  }
  PassResult out;
  State& a = states[0];
  const State& b = states[1];
  a.ts.merge(b.ts);
  a.rs.merge(b.rs);
  a.gs.merge(b.gs);
  a.ys.merge(b.ys);
  out.ts = a.ts;
  out.rs = a.rs;
  out.gs = a.gs;
  out.ys = a.ys;
  out.max_side_top = std::max(a.max_side_top, b.max_side_top);
  if (gram) {
    const auto iq = static_cast<Eigen::Index>(q);
    out.gram.resize(iq, iq);
    for (std::size_t i = 0; i < q; ++i) {
      for (std::size_t j = i; j < q; ++j) {
        CompensatedSum v = a.g_total[i * q4 + j];
        v.add(b.g_total[i * q4 + j].sum);
        v.add(b.g_total[i * q4 + j].comp);
        out.gram(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) =
            out.gram(static_cast<Eigen::Index>(j), static_cast<Eigen::Index>(i)) = v.value();
      }
    }
  }
  return out;
}

// The q x q map M taking each row of [X | y - from_y] (X in the variables of
// `from`) to the same row of [X | y - to_y] (X in those of `to`), so that
// G_to = M G_from M'. Per variable z_to = a z_from + b (a = s_from / s_to,
// b = (c_from - c_to) / s_to) and z_to^k = sum_j C(k, j) a^j b^(k-j) z_from^j,
// the j = 0 term and y's shift on the constant column, the intercept (in the
// paper form, which has none, b = 0 and y is not shifted). False when `from`
// is too far from `to` (see kMaxCenterShift); y_std is the std of y.
bool basis_map(const std::vector<Column>& cols, const Scaling& from, double from_y,
               const Scaling& to, double to_y, double y_std, Eigen::MatrixXd* m) {
  const std::size_t p = cols.size();
  const auto iq = static_cast<Eigen::Index>(p + 1);
  *m = Eigen::MatrixXd::Zero(iq, iq);
  const bool has_constant = !cols.empty() && cols[0].var == 'C';
  const auto close = [](double shift, double scale) {
    return shift == 0 || std::abs(shift) <= kMaxCenterShift * scale;
  };
  for (std::size_t c = 0; c < p; ++c) {
    const Column& col = cols[c];
    const auto ic = static_cast<Eigen::Index>(c);
    if (col.var == 'C') {
      (*m)(ic, ic) = 1;
      continue;
    }
    const double c0 = col.var == 'T'   ? from.t_center
                      : col.var == 'R' ? from.r_center
                                       : from.g_center;
    const double s0 = col.var == 'T' ? from.t_scale : col.var == 'R' ? from.r_scale : from.g_scale;
    const double c1 = col.var == 'T' ? to.t_center : col.var == 'R' ? to.r_center : to.g_center;
    const double s1 = col.var == 'T' ? to.t_scale : col.var == 'R' ? to.r_scale : to.g_scale;
    const double a = s0 / s1;
    const double b = (c0 - c1) / s1;
    if (!(a >= 1 / kMaxScaleRatio && a <= kMaxScaleRatio) || !close(c0 - c1, s1)) return false;
    if (b != 0 && !has_constant) return false;
    const std::size_t first = c - static_cast<std::size_t>(col.power - 1);  // power 1's column
    for (int j = 0; j <= col.power; ++j) {
      const double coef = binomial(col.power, j) * ipow(a, j) * ipow(b, col.power - j);
      if (j == 0) {
        if (b != 0) (*m)(ic, 0) = coef;
      } else {
        (*m)(ic, static_cast<Eigen::Index>(first + static_cast<std::size_t>(j - 1))) = coef;
      }
    }
  }
  const auto ip = static_cast<Eigen::Index>(p);
  (*m)(ip, ip) = 1;
  const double by = from_y - to_y;
  if (by != 0) {
    if (!has_constant || !close(by, y_std)) return false;
    (*m)(ip, 0) = by;
  }
  return true;
}

// Gram path (see drift_model.h) from G = [X | y - y_shift]'[X | y - y_shift]
// in the documented variables: nullopt when the scaled design is too
// ill-conditioned for it (or G is not positive definite).
std::optional<Factor> gram_factor(const Eigen::MatrixXd& g, std::span<const AnalysisSeries> runs,
                                  const std::vector<Column>& cols, const Scaling& sc,
                                  const std::vector<double>& l0, double y_shift,
                                  const DriftFitOptions& options) {
  const std::size_t p = cols.size();
  const std::size_t q4 = (p + 1 + 3) / 4 * 4;
  const auto ip = static_cast<Eigen::Index>(p);
  if (!g.allFinite()) return std::nullopt;
  const Eigen::MatrixXd gxx = g.topLeftCorner(ip, ip);
  const Eigen::VectorXd gxy = g.col(ip).head(ip);
  const double gyy = g(ip, ip);
  // Equilibrate (columns of unit norm), Cholesky, condition number.
  Eigen::VectorXd norm(ip);
  for (Eigen::Index j = 0; j < ip; ++j) {
    if (!(gxx(j, j) > 0) || !std::isfinite(gxx(j, j))) return std::nullopt;
    norm(j) = std::sqrt(gxx(j, j));
  }
  const Eigen::MatrixXd ge =
      norm.cwiseInverse().asDiagonal() * gxx * norm.cwiseInverse().asDiagonal();
  const Eigen::LLT<Eigen::MatrixXd> llt(ge);
  if (llt.info() != Eigen::Success) return std::nullopt;
  const Eigen::MatrixXd re = llt.matrixU();
  const Eigen::VectorXd sv = Eigen::JacobiSVD<Eigen::MatrixXd>(re).singularValues();
  if (!(sv(ip - 1) > 0) || sv(0) / sv(ip - 1) > kGramMaxCondition) return std::nullopt;

  Factor f;
  f.rx = re * norm.asDiagonal();  // R of X: R_e D^-1 with D = diag(1 / norm)
  f.qty = f.rx.transpose().triangularView<Eigen::Lower>().solve(gxy);
  f.rss = gyy - f.qty.squaredNorm();
  // Q'y of the unshifted y: the shift is y_shift times the intercept column
  // (column 0), and Q' column 0 = R e_0.
  if (y_shift != 0) f.qty += y_shift * f.rx.col(0);
  f.solver = "gram";
  if (f.rss >= kGramMinRssFraction * gyy) return f;

  // A close fit: y'y - |Q'y|^2 has lost its digits. One pass over the
  // residuals r = y - X beta gives RSS directly and corrects beta (one step
  // of iterative refinement): Q'y += R^-T X'r, RSS = r'r - |R^-T X'r|^2.
  const auto upper = f.rx.triangularView<Eigen::Upper>();
  const Eigen::VectorXd beta = upper.solve(f.qty);
  struct ResidualState {
    std::vector<double> x, res;
    std::vector<CompensatedSum> xr;
    CompensatedSum rr;
  };
  ResidualState rstates[2];
  for (ResidualState& st : rstates) {
    st.x.assign(q4 * kRowBlock, 0.0);
    st.res.resize(kRowBlock);
    st.xr.resize(p);
  }
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const AnalysisSeries& series = runs[r];
    over_halves(series.t_s.size(), rstates,
                [&](ResidualState& st, std::size_t begin, std::size_t end) {
                  for_each_block(
                      series, options.derivative_window_s,
                      [&](std::size_t i0, std::size_t count, const double* temp,
                          const double* deriv, const double* grad) {
                        fill_columns(cols, sc, count, temp, deriv, grad, st.x.data());
                        double* res = st.res.data();
                        for (std::size_t k = 0; k < count; ++k) {
                          res[k] = series.rate_dph[i0 + k] - l0[r];
                        }
                        for (std::size_t c = 0; c < p; ++c) {
                          const double b = beta(static_cast<Eigen::Index>(c));
                          const double* col = st.x.data() + c * kRowBlock;
                          for (std::size_t k = 0; k < count; ++k) res[k] -= b * col[k];
                        }
                        double s2 = 0;
                        for (std::size_t k = 0; k < count; ++k) s2 += res[k] * res[k];
                        st.rr.add(s2);
                        for (std::size_t c = 0; c < p; ++c) {
                          const double* col = st.x.data() + c * kRowBlock;
                          double sum = 0;
                          for (std::size_t k = 0; k < count; ++k) sum += col[k] * res[k];
                          st.xr[c].add(sum);
                        }
                      },
                      begin, end);
                });
  }
  std::vector<CompensatedSum>& xr = rstates[0].xr;
  CompensatedSum& rr = rstates[0].rr;
  for (std::size_t c = 0; c < p; ++c) xr[c].add(rstates[1].xr[c].value());
  rr.add(rstates[1].rr.value());
  Eigen::VectorXd xtr(ip);
  for (std::size_t c = 0; c < p; ++c) xtr(static_cast<Eigen::Index>(c)) = xr[c].value();
  const Eigen::VectorXd w = f.rx.transpose().triangularView<Eigen::Lower>().solve(xtr);
  f.qty += w;
  f.rss = std::max(0.0, rr.value() - w.squaredNorm());
  f.solver = "gram+refined";
  return f;
}

}  // namespace

Result<DriftFit> fit_drift_model(std::span<const AnalysisSeries> runs, const DriftModelSpec& spec,
                                 DriftModelForm form, const DriftFitOptions& options) {
  std::string why;
  if (!options.is_valid(&why)) return Error::Permanent("drift model options: " + why);
  if (spec.t_order < 0 || spec.t_order > kMaxTermOrder || spec.r_order < 0 ||
      spec.r_order > kMaxTermOrder || spec.g_order < 0 || spec.g_order > kMaxTermOrder ||
      spec.parameters() == 0) {
    return Error::Permanent(
        fmt::format("drift model spec T{} R{} G{}: orders must be 0..{}, not all 0", spec.t_order,
                    spec.r_order, spec.g_order, kMaxTermOrder));
  }
  if (runs.empty()) return Error::Permanent("drift model: no series to fit");
  std::size_t n = 0;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    if (Status st = check_series_named(runs[r], "drift model"); !st.ok()) {
      if (runs.size() == 1) return st.error();
      return Error::Permanent(fmt::format("series {}: {}", r + 1, st.error().message));
    }
    if (runs[r].t_s.size() < 2) {
      return Error::Permanent(fmt::format("drift model: series {} has {} point(s) (need 2)", r + 1,
                                          runs[r].t_s.size()));
    }
    n += runs[r].t_s.size();
  }

  const std::vector<Column> cols = design_columns(spec, form);
  const std::size_t p = cols.size();
  if (n <= p) {
    return Error::Permanent(fmt::format(
        "drift model {}: {} points for {} parameters (need more points than parameters)",
        to_string(spec), n, p));
  }

  // L0 of each series (paper form): only the first l0_window_s of it is read.
  std::vector<double> l0(runs.size(), 0.0);
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const AnalysisSeries& series = runs[r];
    if (form == DriftModelForm::kPaper) {
      CompensatedSum sum;
      std::size_t count = 0;
      for (std::size_t i = 0;
           i < series.t_s.size() && series.t_s[i] - series.t_s[0] < options.l0_window_s; ++i) {
        sum.add(series.rate_dph[i]);
        ++count;
      }
      l0[r] = sum.value() / static_cast<double>(count);
    }
  }
  // One pass: the statistics of T, dT/dt, top - side and y, and (Gram path)
  // the Gram matrix in provisional variables from a sample.
  const bool try_gram = !options.force_householder;
  const Provisional prov =
      try_gram ? provisional_scaling(runs, l0, form, options.derivative_window_s) : Provisional{};
  PassResult pass =
      stats_and_gram(runs, cols, prov.sc, prov.y_center, l0, options.derivative_window_s, try_gram);
  const ShiftedStats& ts = pass.ts;
  const ShiftedStats& rs = pass.rs;
  const ShiftedStats& gs = pass.gs;
  const ShiftedStats& ys = pass.ys;
  const double max_side_top = pass.max_side_top;
  const auto constant = [&](char var, const ShiftedStats& st, double size) -> Status {
    if (st.std_ddof0() <= kConstantTol * size) {
      const char* what = var == 'T'   ? "the mean shell temperature"
                         : var == 'R' ? "dT/dt"
                                      : "the gradient top - side";
      return Error::Permanent(
          fmt::format("drift model {}: term {} cannot be fitted: {} is constant over the series "
                      "(mean {}, std {})",
                      to_string(spec), var, what, st.mean(), st.std_ddof0()));
    }
    return Status::Ok();
  };
  if (spec.t_order > 0) {
    if (Status st = constant('T', ts, ts.max_abs); !st.ok()) return st.error();
  }
  if (spec.r_order > 0) {
    if (Status st = constant('R', rs, ts.max_abs / options.derivative_window_s); !st.ok()) {
      return st.error();
    }
  }
  if (spec.g_order > 0) {
    if (Status st = constant('G', gs, max_side_top); !st.ok()) return st.error();
  }
  Scaling sc{};
  if (form == DriftModelForm::kPaper) {
    sc = {0, ts.max_abs, 0, rs.max_abs, 0, gs.max_abs};
  } else {
    sc = {ts.mean(), ts.std_ddof0(), rs.mean(), rs.std_ddof0(), gs.mean(), gs.std_ddof0()};
  }
  // Unused variables keep a harmless scale.
  if (!(sc.t_scale > 0)) sc.t_scale = 1;
  if (!(sc.r_scale > 0)) sc.r_scale = 1;
  if (!(sc.g_scale > 0)) sc.g_scale = 1;

  // The triangular factor, by the Gram path when the scaled design is well
  // conditioned, else by Householder QR (another pass).
  std::optional<Factor> factor;
  if (try_gram) {
    // The centred form has an intercept: y is centred for the Gram matrix too.
    const double y_shift = form == DriftModelForm::kCentered ? ys.mean() : 0.0;
    Eigen::MatrixXd m;
    Eigen::MatrixXd g;
    if (basis_map(cols, prov.sc, prov.y_center, sc, y_shift, ys.std_ddof0(), &m)) {
      g = m * pass.gram * m.transpose();
    } else {
      g = stats_and_gram(runs, cols, sc, y_shift, l0, options.derivative_window_s, true).gram;
    }
    factor = gram_factor(g, runs, cols, sc, l0, y_shift, options);
  }
  if (!factor) factor = householder_factor(runs, cols, sc, l0, options);
  const auto ip = static_cast<Eigen::Index>(p);
  const Eigen::MatrixXd& rx = factor->rx;
  const Eigen::VectorXd& qty = factor->qty;
  const double rss = factor->rss;
  // Rank: |R_jj| / |column j| is the sine of the angle between column j and the
  // span of the columns before it.
  Eigen::VectorXd col_norm(ip);
  for (Eigen::Index j = 0; j < ip; ++j) col_norm(j) = rx.col(j).head(j + 1).norm();
  for (Eigen::Index j = 0; j < ip; ++j) {
    const double sine = col_norm(j) > 0 ? std::abs(rx(j, j)) / col_norm(j) : 0;
    if (!(sine > options.rank_tolerance)) {
      return Error::Permanent(fmt::format(
          "drift model {} ({} form): design is rank-deficient at term {}: it is (nearly) a "
          "combination of the terms before it (relative size {:.3g}, tolerance {:.3g})",
          to_string(spec), to_string(form), column_name(cols[static_cast<std::size_t>(j)]), sine,
          options.rank_tolerance));
    }
  }
  const Eigen::MatrixXd rn = rx * col_norm.cwiseInverse().asDiagonal();
  const Eigen::VectorXd sv = Eigen::JacobiSVD<Eigen::MatrixXd>(rn).singularValues();

  const auto upper = rx.triangularView<Eigen::Upper>();
  const Eigen::VectorXd beta = upper.solve(qty);
  const Eigen::MatrixXd rinv = upper.solve(Eigen::MatrixXd::Identity(ip, ip));
  const double dof = static_cast<double>(n - p);
  const double sigma2 = rss / dof;
  const Eigen::MatrixXd cov_beta = sigma2 * (rinv * rinv.transpose());

  // Physical coefficients a = M beta: expand sum_i b_i ((x - c) / s)^i.
  Eigen::MatrixXd m = Eigen::MatrixXd::Zero(ip, ip);
  for (std::size_t a = 0; a < p; ++a) {
    for (std::size_t b = 0; b < p; ++b) {
      const Column& ca = cols[a];
      const Column& cb = cols[b];
      if (cb.var == 'C') {
        if (ca.var == 'C') m(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)) = 1;
        continue;
      }
      const double c = cb.var == 'T' ? sc.t_center : cb.var == 'R' ? sc.r_center : sc.g_center;
      const double s = cb.var == 'T' ? sc.t_scale : cb.var == 'R' ? sc.r_scale : sc.g_scale;
      const int k = ca.var == 'C' ? 0 : ca.power;
      if ((ca.var != 'C' && ca.var != cb.var) || k > cb.power) continue;
      m(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)) =
          binomial(cb.power, k) * ipow(-c, cb.power - k) / ipow(s, cb.power);
    }
  }
  const Eigen::VectorXd phys = m * beta;
  const Eigen::MatrixXd cov_phys = m * cov_beta * m.transpose();

  DriftFit fit;
  fit.spec = spec;
  fit.form = form;
  fit.n = n;
  fit.parameters = p;
  fit.residual_std_dph = std::sqrt(sigma2);
  const double tss = static_cast<double>(ys.n) * ys.std_ddof0() * ys.std_ddof0();
  fit.r_squared = tss > 0 ? 1 - rss / tss : 1.0;
  fit.l0_dph = l0.front();
  fit.l0_per_series_dph = l0;
  fit.condition_estimate = sv(0) / sv(ip - 1);
  fit.solver = factor->solver;
  fit.derivative_window_s = options.derivative_window_s;
  fit.t_center = sc.t_center;
  fit.t_scale = sc.t_scale;
  fit.r_center = sc.r_center;
  fit.r_scale = sc.r_scale;
  fit.g_center = sc.g_center;
  fit.g_scale = sc.g_scale;
  for (std::size_t c = 0; c < p; ++c) {
    const auto j = static_cast<Eigen::Index>(c);
    const std::string name = column_name(cols[c]);
    fit.column_names.push_back(name);
    fit.scaled_coefficients.push_back(beta(j));
    fit.coefficients[name] = phys(j);
    fit.std_errors[name] = std::sqrt(std::max(0.0, cov_phys(j, j)));
  }
  return fit;
}

Result<std::vector<double>> predict_drift(const DriftFit& fit, const AnalysisSeries& series) {
  if (Status st = check_series_named(series, "drift model"); !st.ok()) return st.error();
  const std::vector<Column> cols = design_columns(fit.spec, fit.form);
  if (cols.size() != fit.scaled_coefficients.size()) {
    return Error::Permanent("predict_drift: the fit's coefficients do not match its spec");
  }
  const Scaling sc{fit.t_center, fit.t_scale, fit.r_center, fit.r_scale, fit.g_center, fit.g_scale};
  std::vector<double> out(series.t_s.size());
  std::vector<double> row(cols.size());
  for_each_block(series, fit.derivative_window_s,
                 [&](std::size_t i0, std::size_t count, const double* temp, const double* deriv,
                     const double* grad) {
                   for (std::size_t k = 0; k < count; ++k) {
                     fill_row(cols, sc, temp[k], deriv[k], grad[k], row.data());
                     double v = fit.l0_dph;
                     for (std::size_t c = 0; c < cols.size(); ++c) {
                       v += fit.scaled_coefficients[c] * row[c];
                     }
                     out[i0 + k] = v;
                   }
                 });
  return out;
}

Result<std::vector<double>> drift_terms(const DriftFit& fit, const AnalysisSeries& series) {
  auto predicted = predict_drift(fit, series);
  if (!predicted) return predicted;
  // The model at T = 0, dT/dt = 0, dT = 0 in the fit's scaled variables.
  const std::vector<Column> cols = design_columns(fit.spec, fit.form);
  const Scaling sc{fit.t_center, fit.t_scale, fit.r_center, fit.r_scale, fit.g_center, fit.g_scale};
  std::vector<double> row(cols.size());
  fill_row(cols, sc, 0.0, 0.0, 0.0, row.data());
  double at_zero = fit.l0_dph;
  for (std::size_t c = 0; c < cols.size(); ++c) at_zero += fit.scaled_coefficients[c] * row[c];
  for (double& v : *predicted) v -= at_zero;
  return predicted;
}

std::vector<std::string> coefficient_names(const DriftModelSpec& spec, DriftModelForm form) {
  std::vector<std::string> names;
  for (const Column& c : design_columns(spec, form)) names.push_back(column_name(c));
  return names;
}

std::string_view form_label(DriftModelForm form) {
  return form == DriftModelForm::kPaper
             ? "the paper's form (L − L0, no intercept; biased when runs start away from 0 °C)"
             : "centred form";
}

std::vector<std::string> near_zero_coefficients(const DriftFit& fit, double sigmas) {
  std::vector<std::string> out;
  for (const std::string& name : coefficient_names(fit.spec, fit.form)) {
    if (name == "intercept") continue;
    const auto c = fit.coefficients.find(name);
    const auto e = fit.std_errors.find(name);
    if (c == fit.coefficients.end() || e == fit.std_errors.end()) continue;
    if (!std::isfinite(e->second) || !(std::abs(c->second) >= sigmas * e->second)) {
      out.push_back(name);
    }
  }
  return out;
}

std::string near_zero_warning(const DriftFit& fit, double sigmas) {
  const auto names = near_zero_coefficients(fit, sigmas);
  if (names.empty()) return "";
  std::string list;
  for (const auto& n : names) list += (list.empty() ? "" : ", ") + n;
  return fmt::format(
      "{} within {:g} standard errors of zero: not determined by these data (a lower order or "
      "more varied runs may be needed)",
      list, sigmas);
}

std::string coefficient_unit(const std::string& name) {
  if (name == "intercept") return "°/h";
  if (name.size() != 2) return "";
  const char power = name[1];
  const std::string sup = power == '1' ? "" : power == '2' ? "²" : power == '3' ? "³" : "⁴";
  if (name[0] == 'R') return power == '1' ? "°/h per °C/s" : "°/h per (°C/s)" + sup;
  return "°/h per °C" + sup;
}

Status check_analysis_series(const AnalysisSeries& series, std::string_view what) {
  return check_series_named(series, what);
}

}  // namespace gyrotherm::analysis
