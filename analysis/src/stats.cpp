// Plain statistics of table1.h and the fused Table I pass, in double.
//
// The data is cut into blocks of kBlock points (in L1/L2 while a block is
// worked on). Each block gets its exact two-pass moments (sum, then the sum of
// squared deviations from the block's own mean); the blocks are combined at
// the end with the exact decomposition
//   M2 = sum_b M2_b + sum_b n_b (mean_b - mean)^2,  mean = (sum_b sum_b) / n
// (block sums added with Neumaier compensation). So a large common offset
// (rates around 1e4 °/h) costs no digits, and the rounding error is about
// (kBlock / 8 + log n) eps relative instead of n eps. table1_statistics
// reads each block once: one-pass sums shifted by the previous block's mean
// (refused, and redone in two passes, if the shift would cancel a digit).
#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>
#include <vector>

#include "common.h"
#include "compensated_sum.h"
#include "gyrotherm/analysis/table1.h"

namespace gyrotherm::analysis {
namespace {

constexpr std::size_t kBlock = 4096;
constexpr std::size_t kLanes = 4;  // independent running window sums per block
// Series at least this long are summed on two threads (table1_statistics).
constexpr std::size_t kParallelPoints = std::size_t{1} << 18;

// Sums with 8 independent accumulators so that the compiler vectorises them.
double block_sum(const double* x, std::size_t n) {
  double a[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    for (std::size_t j = 0; j < 8; ++j) a[j] += x[i + j];
  }
  for (; i < n; ++i) a[0] += x[i];
  return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
}

// Sum of x - c and of (x - c)^2 over a block.
void block_dev(const double* x, std::size_t n, double c, double* sum_d, double* sum_d2) {
  double a[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  double q[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    for (std::size_t j = 0; j < 8; ++j) {
      const double d = x[i + j] - c;
      a[j] += d;
      q[j] += d * d;
    }
  }
  for (; i < n; ++i) {
    a[0] += x[i] - c;
    q[0] += (x[i] - c) * (x[i] - c);
  }
  *sum_d = ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]));
  *sum_d2 = ((q[0] + q[1]) + (q[2] + q[3])) + ((q[4] + q[5]) + (q[6] + q[7]));
}

// Moments of a sequence built block by block (see the top of the file).
class BlockedMoments {
 public:
  explicit BlockedMoments(std::size_t expected_blocks) { blocks_.reserve(expected_blocks); }
  // A block of n values shift + v_i, with sum_v = sum of v_i: two more passes
  // over v while it is in cache give its mean and M2 (the second pass about
  // the rounded mean of v, corrected by the sum of the deviations).
  void add_block(const double* v, std::size_t n, double shift, double sum_v) {
    const double nb = static_cast<double>(n);
    double c = sum_v / nb;
    // Constant data: deviate from the data's own value, not a rounded mean.
    if (std::abs(c - v[0]) <= 1e-12 * std::abs(c)) c = v[0];
    double sd = 0, sd2 = 0;
    block_dev(v, n, c, &sd, &sd2);
    blocks_.push_back({nb, shift + (c + sd / nb), std::max(0.0, sd2 - sd * sd / nb)});
    if (shift != 0) total_.add(shift * nb);
    total_.add(sum_v);
    n_ += n;
  }
  // A block given by one-pass sums of d = value - shift: sd = sum d, sd2 =
  // sum d^2. Refused (false, nothing added) when the shift is so far from the
  // block's mean that sd2 - sd^2 / n would cancel more than one digit; the
  // caller then uses add_block.
  bool add_shifted(std::size_t n, double shift, double sd, double sd2) {
    const double nb = static_cast<double>(n);
    const double between = sd * sd / nb;
    if (between > 0.9 * sd2) return false;
    blocks_.push_back({nb, shift + sd / nb, sd2 - between});
    if (shift != 0) total_.add(shift * nb);
    total_.add(sd);
    n_ += n;
    return true;
  }
  void merge(const BlockedMoments& o) {
    blocks_.insert(blocks_.end(), o.blocks_.begin(), o.blocks_.end());
    total_.add(o.total_.sum);
    total_.add(o.total_.comp);
    n_ += o.n_;
  }
  std::size_t n() const { return n_; }
  double last_mean() const { return blocks_.back().mean; }
  double mean() const { return total_.value() / static_cast<double>(n_); }
  double m2() const {
    // The mean for the between-block term as c0 + mean(mean_b - c0): exact
    // when every block has the same mean.
    const double c0 = blocks_.front().mean;
    double dm = 0;
    for (const Block& b : blocks_) dm += b.n * (b.mean - c0);
    const double m = c0 + dm / static_cast<double>(n_);
    double within = 0, between = 0;
    for (const Block& b : blocks_) {
      within += b.m2;
      between += b.n * (b.mean - m) * (b.mean - m);
    }
    return within + between;
  }
  double std_ddof1() const {
    if (n_ < 2) return kNaN;
    const double v = m2() / static_cast<double>(n_ - 1);
    return std::isfinite(v) ? std::sqrt(v) : kNaN;
  }

 private:
  struct Block {
    double n, mean, m2;
  };
  std::vector<Block> blocks_;
  CompensatedSum total_;
  std::size_t n_ = 0;
};

std::size_t blocks_for(std::size_t n) { return n / kBlock + 1; }

// Moving-average means m_k = (x_k + ... + x_{k+w-1}) / w for k in [k0, k1),
// written to out[0 .. k1 - k0). Each of kLanes stretches starts from a fresh
// window sum of x - shift and then slides (S += x_{k+w} - x_k), so the
// rounding of the running sums never spans more than kBlock / kLanes steps.
void moving_means(const double* x, std::size_t w, std::size_t k0, std::size_t k1, double shift,
                  double* out) {
  const std::size_t count = k1 - k0;
  const std::size_t per_lane = (count + kLanes - 1) / kLanes;
  double s[kLanes];
  std::size_t start[kLanes], len[kLanes];
  for (std::size_t l = 0; l < kLanes; ++l) {
    start[l] = std::min(k0 + l * per_lane, k1);
    len[l] = std::min(per_lane, k1 - start[l]);
    double a = 0;
    if (len[l] > 0) {
      for (std::size_t j = 0; j < w; ++j) a += x[start[l] + j] - shift;
    }
    s[l] = a;
  }
  const double inv_w = 1.0 / static_cast<double>(w);
  // All lanes but possibly the last have per_lane values; interleave them.
  for (std::size_t i = 0; i < per_lane; ++i) {
    for (std::size_t l = 0; l < kLanes; ++l) {
      if (i >= len[l]) continue;
      const std::size_t k = start[l] + i;
      out[k - k0] = s[l] * inv_w;
      if (i + 1 < len[l]) s[l] += x[k + w] - x[k];
    }
  }
}

// Sum and sum of squares of m_k - shift over k in [k0, k1), the m_k as in
// moving_means, without storing them: kLanes running sums advance together.
void moving_mean_moments(const double* x, std::size_t w, std::size_t k0, std::size_t k1,
                         double shift, double* sum_d, double* sum_d2) {
  const std::size_t count = k1 - k0;
  const std::size_t per_lane = count / kLanes;
  const double inv_w = 1.0 / static_cast<double>(w);
  double s[kLanes], a[kLanes], q[kLanes];
  for (std::size_t l = 0; l < kLanes; ++l) {
    const double* xs = x + k0 + l * per_lane;
    double v = 0;
    for (std::size_t j = 0; j < w; ++j) v += xs[j] - shift;
    s[l] = v;
    a[l] = q[l] = 0;
  }
  // Lane l covers k0 + l * per_lane + i, i < per_lane; the last lane also the rest.
  // Each window sum advances after its mean is taken, except after a lane's
  // last mean: that would read x[k0 + kLanes * per_lane - 1 + w], one past the
  // data when the last lane has no rest (x holds k1 - 1 + w points).
  constexpr std::size_t last = kLanes - 1;
  for (std::size_t i = 0; i + 1 < per_lane; ++i) {
    for (std::size_t l = 0; l < kLanes; ++l) {
      const double* xs = x + k0 + l * per_lane + i;
      const double m = s[l] * inv_w;
      a[l] += m;
      q[l] += m * m;
      s[l] += xs[w] - xs[0];
    }
  }
  if (per_lane > 0) {
    for (std::size_t l = 0; l < kLanes; ++l) {
      const double m = s[l] * inv_w;
      a[l] += m;
      q[l] += m * m;
    }
    const std::size_t k = k0 + kLanes * per_lane - 1;  // the last lane's last point
    if (k + 1 < k1) s[last] += x[k + w] - x[k];
  }
  for (std::size_t k = k0 + kLanes * per_lane; k < k1; ++k) {
    const double m = s[last] * inv_w;
    a[last] += m;
    q[last] += m * m;
    if (k + 1 < k1) s[last] += x[k + w] - x[k];
  }
  *sum_d = (a[0] + a[1]) + (a[2] + a[3]);
  *sum_d2 = (q[0] + q[1]) + (q[2] + q[3]);
}

// Sum of d = x - c, of d^2 and of top + side over a block, in one pass.
void rate_shell_sums(const double* x, const double* top, const double* side, std::size_t n,
                     double c, double* sum_d, double* sum_d2, double* sum_shell2) {
  double a[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  double q[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  double h[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    for (std::size_t j = 0; j < 8; ++j) {
      const double d = x[i + j] - c;
      a[j] += d;
      q[j] += d * d;
      h[j] += top[i + j] + side[i + j];
    }
  }
  for (; i < n; ++i) {
    a[0] += x[i] - c;
    q[0] += (x[i] - c) * (x[i] - c);
    h[0] += top[i] + side[i];
  }
  const auto total = [](const double* v) {
    return ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]));
  };
  *sum_d = total(a);
  *sum_d2 = total(q);
  *sum_shell2 = total(h);
}

}  // namespace

double mean(std::span<const double> x) {
  if (x.empty()) return kNaN;
  CompensatedSum total;
  for (std::size_t b = 0; b < x.size(); b += kBlock) {
    total.add(block_sum(x.data() + b, std::min(kBlock, x.size() - b)));
  }
  const double m = total.value() / static_cast<double>(x.size());
  return std::isfinite(m) ? m : kNaN;
}

double std_ddof1(std::span<const double> x) {
  if (x.size() < 2) return kNaN;
  BlockedMoments mom(blocks_for(x.size()));
  for (std::size_t b = 0; b < x.size(); b += kBlock) {
    const std::size_t nb = std::min(kBlock, x.size() - b);
    mom.add_block(x.data() + b, nb, 0.0, block_sum(x.data() + b, nb));
  }
  return mom.std_ddof1();
}

double moving_average_std(std::span<const double> x, std::size_t window) {
  if (window == 0 || x.size() < window + 1) return kNaN;
  const std::size_t nma = x.size() - window + 1;
  BlockedMoments mom(blocks_for(nma));
  std::vector<double> buf(kBlock);
  for (std::size_t b = 0; b < nma; b += kBlock) {
    const std::size_t e = std::min(b + kBlock, nma);
    const double shift = x[b];
    moving_means(x.data(), window, b, e, shift, buf.data());
    mom.add_block(buf.data(), e - b, shift, block_sum(buf.data(), e - b));
  }
  return mom.std_ddof1();
}

Table1Statistics table1_statistics(std::span<const double> rate_dph, std::span<const double> top_c,
                                   std::span<const double> side_c, std::size_t ma_window) {
  Table1Statistics out;
  const std::size_t n = rate_dph.size();
  out.n = n;
  if (n < 2 || top_c.size() != n || side_c.size() != n || ma_window == 0) {
    out.finite = false;
    return out;
  }
  const double* r = rate_dph.data();
  const std::size_t nma = n >= ma_window + 1 ? n - ma_window + 1 : 0;
  struct Part {
    BlockedMoments rate{0}, ma{0};
    CompensatedSum shell2;  // sum of top + side
    bool finite = true;
  };
  // Blocks [b_begin, b_end) (in points, multiples of kBlock) into part.
  const auto run = [&](Part& part, std::size_t b_begin, std::size_t b_end) {
    std::vector<double> buf;
    // The shift of each block's one-pass sums: the previous block's mean (the
    // first block: the mean of its first points).
    const std::size_t k = std::min<std::size_t>(b_end - b_begin, 64);
    double shift = block_sum(r + b_begin, k) / static_cast<double>(k);
    if (!std::isfinite(shift)) shift = 0;
    for (std::size_t b = b_begin; b < b_end; b += kBlock) {
      const std::size_t nb = std::min(kBlock, b_end - b);
      double sd = 0, sd2 = 0, sh = 0;
      rate_shell_sums(r + b, top_c.data() + b, side_c.data() + b, nb, shift, &sd, &sd2, &sh);
      // A NaN or infinity anywhere in the block makes its sums non-finite.
      if (!std::isfinite(sd2) || !std::isfinite(sh)) {
        part.finite = false;
        return;
      }
      part.shell2.add(sh);
      if (!part.rate.add_shifted(nb, shift, sd, sd2)) {
        part.rate.add_block(r + b, nb, 0.0, block_sum(r + b, nb));
      }
      if (b < nma) {
        const std::size_t e = std::min(b + kBlock, nma);
        double md = 0, md2 = 0;
        moving_mean_moments(r, ma_window, b, e, shift, &md, &md2);
        if (!part.ma.add_shifted(e - b, shift, md, md2)) {
          buf.resize(kBlock);
          moving_means(r, ma_window, b, e, shift, buf.data());
          part.ma.add_block(buf.data(), e - b, shift, block_sum(buf.data(), e - b));
        }
      }
      shift = part.rate.last_mean();
    }
  };
  Part parts[2];
  if (n < kParallelPoints) {
    run(parts[0], 0, n);
  } else {
    // Two threads, each on half of the blocks; the moments combine exactly.
    const std::size_t mid = n / 2 / kBlock * kBlock;
    std::thread other([&] { run(parts[1], mid, n); });
    run(parts[0], 0, mid);
    other.join();
    parts[0].finite = parts[0].finite && parts[1].finite;
    parts[0].rate.merge(parts[1].rate);
    parts[0].ma.merge(parts[1].ma);
    parts[0].shell2.add(parts[1].shell2.sum);
    parts[0].shell2.add(parts[1].shell2.comp);
  }
  if (!parts[0].finite) {
    out.finite = false;
    return out;
  }
  const BlockedMoments& rate = parts[0].rate;
  const BlockedMoments& ma = parts[0].ma;
  const CompensatedSum& shell2 = parts[0].shell2;
  out.temp_mean_c = shell2.value() / (2.0 * static_cast<double>(n));
  out.bias_mean_dph = rate.mean();
  out.bias_std_dph = rate.std_ddof1();
  out.bias_std_ma_dph = nma >= 2 ? ma.std_ddof1() : kNaN;
  out.finite = std::isfinite(out.temp_mean_c) && std::isfinite(out.bias_mean_dph) &&
               std::isfinite(out.bias_std_dph);
  return out;
}

double linear_slope(std::span<const double> t, std::span<const double> y) {
  if (t.size() != y.size() || t.size() < 2) return kNaN;
  const double tm = mean(t);
  const double ym = mean(y);
  if (!std::isfinite(tm) || !std::isfinite(ym)) return kNaN;
  double stt = 0;
  double sty = 0;
  for (std::size_t i = 0; i < t.size(); ++i) {
    const double dt = t[i] - tm;
    stt += dt * dt;
    sty += dt * (y[i] - ym);
  }
  if (!(stt > 0)) return kNaN;
  return sty / stt;
}

}  // namespace gyrotherm::analysis
