// The overlapping Allan deviation of a streamed series (allan.h): prefix sums
// in memory up to a limit, beyond it in an unnamed scratch file swept in
// windows; the noise identified from running sums.
#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <optional>
#include <vector>

#include "allan_detail.h"
#include "compensated_sum.h"
#include "gyrotherm/analysis/allan.h"

namespace gyrotherm::analysis {
namespace {

// An unnamed file of doubles in a directory, deleted when closed: the
// prefix sums of a series too long to hold.
class ScratchFile {
 public:
  static Result<std::unique_ptr<ScratchFile>> create(std::string dir) {
    if (dir.empty()) {
      const char* env = std::getenv("TMPDIR");
      dir = env != nullptr && *env != '\0' ? env : "/tmp";
    }
    int fd = ::open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
    if (fd < 0) {  // a file system without O_TMPFILE: a named file, unlinked at once
      std::string path = dir + "/gyrotherm-allan-XXXXXX";
      fd = ::mkstemp(path.data());
      if (fd >= 0) ::unlink(path.c_str());
    }
    if (fd < 0) {
      return Error::Transient(fmt::format(
          "cannot create a scratch file in {} for the prefix sums: {}", dir, std::strerror(errno)));
    }
    return std::unique_ptr<ScratchFile>(new ScratchFile(fd, std::move(dir)));
  }
  ~ScratchFile() { ::close(fd_); }
  ScratchFile(const ScratchFile&) = delete;
  ScratchFile& operator=(const ScratchFile&) = delete;

  Status append(const double* v, std::size_t count) {
    const char* p = reinterpret_cast<const char*>(v);
    std::size_t left = count * sizeof(double);
    while (left > 0) {
      const ssize_t w = ::write(fd_, p, left);
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) {
        return Error::Transient(fmt::format("scratch file in {}: writing {} bytes after {}: {}",
                                            dir_, left, bytes_, std::strerror(errno)));
      }
      p += w;
      left -= static_cast<std::size_t>(w);
      bytes_ += static_cast<std::size_t>(w);
    }
    return Status::Ok();
  }

  // Doubles [index, index + count) into out.
  Status read(std::size_t index, std::size_t count, double* out) const {
    char* p = reinterpret_cast<char*>(out);
    std::size_t left = count * sizeof(double);
    auto at = static_cast<off_t>(index * sizeof(double));
    while (left > 0) {
      const ssize_t r = ::pread(fd_, p, left, at);
      if (r < 0 && errno == EINTR) continue;
      if (r <= 0) {
        return Error::Transient(fmt::format("scratch file in {}: reading {} bytes at {}: {}", dir_,
                                            left, at,
                                            r == 0 ? "end of file" : std::strerror(errno)));
      }
      p += r;
      at += r;
      left -= static_cast<std::size_t>(r);
    }
    return Status::Ok();
  }

 private:
  ScratchFile(int fd, std::string dir) : fd_(fd), dir_(std::move(dir)) {}
  int fd_;
  std::string dir_;
  std::size_t bytes_ = 0;
};

// A running sum taken kRun values at a time in plain double (cheap: it is
// fed every block mean of every tau), each run's total then added
// compensated: the error stays ~(kRun + runs) eps, not n eps.
class RunningSum {
 public:
  void add(double v) {
    run_ += v;
    if (++count_ == kRun) flush();
  }
  double value() const { return total_.value() + run_; }

 private:
  static constexpr int kRun = 1024;
  void flush() {
    total_.add(run_);
    run_ = 0;
    count_ = 0;
  }
  CompensatedSum total_;
  double run_ = 0;
  int count_ = 0;
};

// r1 / (1 + r1) of a series fed one value at a time, centred on its mean:
// den = sum (v - mean)^2, num = sum (v_i - mean)(v_{i+1} - mean), from
// running sums (a constant added to every value changes nothing).
class LagSums {
 public:
  void add(double v) {
    if (count_ == 0) first_ = v;
    if (count_ > 0) p_.add(prev_ * v);
    s_.add(v);
    q_.add(v * v);
    prev_ = v;
    ++count_;
  }
  // nullopt for a constant series.
  std::optional<double> delta() const {
    const auto l = static_cast<double>(count_);
    const double s = s_.value();
    const double mean = s / l;
    const double den = q_.value() - s * mean;
    const double num = p_.value() - mean * (2.0 * s - first_ - prev_) + (l - 1.0) * mean * mean;
    if (!(den > 0)) return std::nullopt;
    const double r1 = num / den;
    return r1 / (1.0 + r1);
  }

 private:
  std::size_t count_ = 0;
  double first_ = 0, prev_ = 0;
  RunningSum s_, q_, p_;
};

// identify_noise_lag1's statistic on block means fed in order, in O(1)
// memory: the detrended series' lag-1 sums from the raw sums S = sum y,
// Q = sum y^2, T = sum i y, P = sum y_i y_{i+1} (y: the block means less the
// first), expanded with z_i = (y_i - ybar) - beta (i - ibar); its first and
// second differences (the trend is a constant there, which centring
// removes) by LagSums.
class Lag1Identifier {
 public:
  void add(double x) {
    if (k_ == 0) x0_ = x;
    const double y = x - x0_;
    const auto i = static_cast<double>(k_);
    s_.add(y);
    q_.add(y * y);
    t_.add(i * y);
    if (k_ > 0) {
      p_.add(y_prev_ * y);
      const double u = y - y_prev_;
      d1_.add(u);
      if (k_ > 1) d2_.add(u - u_prev_);
      u_prev_ = u;
    }
    y_prev_ = y;
    ++k_;
  }

  std::optional<NoiseIdentification> result() const {
    if (k_ < kMinNoiseIdAverages) return std::nullopt;
    const auto k = static_cast<double>(k_);
    const double s = s_.value(), q = q_.value(), t = t_.value(), p = p_.value();
    const double ybar = s / k, ibar = (k - 1.0) / 2.0;
    const double sxy = t - ibar * s;
    const double sii = k * (k * k - 1.0) / 12.0;
    const double beta = sxy / sii;
    const double a_first = -ybar, a_last = y_prev_ - ybar;
    const double e_last = ibar, e_first = -ibar;
    const double den = (q - s * ybar) - beta * sxy;
    const double sum_aa = p - ybar * (2.0 * s - y_prev_) + (k - 1.0) * ybar * ybar;
    const double sum_a_e_next = sxy - a_last * (e_last + 1.0);
    const double sum_a_next_e = sxy - a_first * (e_first - 1.0);
    const double sum_ee = sii - e_last * e_last - e_last;
    const double num = sum_aa - beta * (sum_a_e_next + sum_a_next_e) + beta * beta * sum_ee;
    if (!(den > 0)) return std::nullopt;
    const double r1 = num / den;
    std::optional<double> delta = r1 / (1.0 + r1);
    NoiseIdentification id;
    id.averages = k_;
    constexpr int kMaxDifferences = 2;  // the Allan variance's own order
    for (int d = 0;; ++d) {
      if (!delta) return std::nullopt;
      if (*delta < 0.25 || d >= kMaxDifferences) {
        id.differences = d;
        id.delta = *delta;
        id.alpha_estimate = -2.0 * (*delta + d);
        id.alpha = std::clamp(static_cast<int>(std::lround(id.alpha_estimate)), -2, 2);
        return id;
      }
      delta = d == 0 ? d1_.delta() : d2_.delta();
    }
  }

 private:
  std::size_t k_ = 0;
  double x0_ = 0, y_prev_ = 0, u_prev_ = 0;
  RunningSum s_, q_, t_, p_;
  LagSums d1_, d2_;
};

// Where the prefix sums go while they are built: memory or the scratch file.
// Each block of C also feeds the block means of every cluster size whose
// noise is identified (n / m >= kMinNoiseIdAverages).
struct PrefixSink {
  double* memory = nullptr;  // C[0 .. n] when in memory
  ScratchFile* file = nullptr;
  std::vector<double> pending;  // C values not yet written to the file

  struct Blocks {
    std::size_t m;
    std::size_t next;  // the next block boundary q (C index), multiple of m
    std::size_t last;  // the last boundary: (n / m) m
    double c_prev = 0;
    Lag1Identifier id;
  };
  std::vector<Blocks> blocks;
};

constexpr std::size_t kFileChunk = std::size_t{1} << 16;  // doubles per write

// Pass 2: C[0 .. n] (prefix_block per kBlock rates, exactly as the in-memory
// path builds it) into the sink.
Status build_prefix(const SampleSource& source, std::size_t n, double shift, PrefixSink& sink) {
  using allan_detail::kBlock;
  std::vector<double> y(kBlock), c(kBlock);
  CompensatedSum offset;
  std::size_t b = 0, filled = 0;  // C indices written: [0, b]; rates staged: filled
  Status failed = Status::Ok();
  const auto flush = [&]() -> bool {
    allan_detail::prefix_block(y.data(), filled, shift, offset, c.data());
    // c[i] = C[b + 1 + i]
    const std::size_t e = b + filled;
    for (PrefixSink::Blocks& bl : sink.blocks) {
      while (bl.next <= e && bl.next <= bl.last) {
        const double cq = c[bl.next - b - 1];
        bl.id.add((cq - bl.c_prev) / static_cast<double>(bl.m));
        bl.c_prev = cq;
        bl.next += bl.m;
      }
    }
    if (sink.memory != nullptr) {
      std::copy(c.begin(), c.begin() + static_cast<std::ptrdiff_t>(filled), sink.memory + b + 1);
    } else {
      sink.pending.insert(sink.pending.end(), c.begin(),
                          c.begin() + static_cast<std::ptrdiff_t>(filled));
      if (sink.pending.size() >= kFileChunk) {
        if (Status st = sink.file->append(sink.pending.data(), sink.pending.size()); !st) {
          failed = st;
          return false;
        }
        sink.pending.clear();
      }
    }
    b = e;
    filled = 0;
    return true;
  };
  if (sink.memory != nullptr) {
    sink.memory[0] = 0;
  } else {
    sink.pending.push_back(0);
  }
  std::size_t seen = 0;
  Status st = source([&](std::span<const double>, std::span<const double> rate) {
    for (const double v : rate) {
      if (seen++ == n) return false;  // the source grew since the scan: its first n
      y[filled++] = v;
      if (filled == kBlock && !flush()) return false;
    }
    return true;
  });
  if (!st) return st;
  if (!failed.ok()) return failed;
  if (filled > 0 && !flush()) return failed;
  if (b != n) {
    return Error::Transient(fmt::format(
        "the series changed between two passes: {} samples on the second, {} on the first", b, n));
  }
  if (sink.file != nullptr && !sink.pending.empty()) {
    if (Status s = sink.file->append(sink.pending.data(), sink.pending.size()); !s) return s;
    sink.pending.clear();
  }
  return Status::Ok();
}

// The variances from C in the scratch file, a window of w offsets at a time.
// Small m (2m <= w): one read of C[k0 .. k0 + w + 2 m_max] per window serves
// every small m; large m: three reads per window, at k0, k0 + m, k0 + 2m.
Result<std::vector<double>> swept_variances(const ScratchFile& file, std::size_t n,
                                            const std::vector<std::size_t>& ms, std::size_t w) {
  constexpr std::size_t kChunk = 1024;  // offsets per kernel call: C stretches stay in cache
  const auto terms = [&](std::size_t j) { return n - 2 * ms[j] + 1; };
  std::vector<CompensatedSum> ss(ms.size());
  std::size_t small_end = 0;
  while (small_end < ms.size() && 2 * ms[small_end] <= w) ++small_end;
  if (small_end > 0) {
    const std::size_t m_max = ms[small_end - 1];
    std::vector<double> buf(w + 2 * m_max);
    for (std::size_t k0 = 0; k0 < terms(0); k0 += w) {
      const std::size_t len = std::min(w + 2 * m_max, n + 1 - k0);
      if (Status st = file.read(k0, len, buf.data()); !st) return st.error();
      const std::size_t k_end = std::min(k0 + w, terms(0));
      for (std::size_t kc = k0; kc < k_end; kc += kChunk) {
        for (std::size_t j = 0; j < small_end; ++j) {
          const std::size_t end = std::min({kc + kChunk, k_end, terms(j)});
          if (kc >= end) break;  // larger m have fewer terms still
          const double* c = buf.data() + (kc - k0);
          ss[j].add(allan_detail::cluster_diff_squares(c, c + ms[j], c + 2 * ms[j], end - kc));
        }
      }
    }
  }
  if (small_end < ms.size()) {
    std::vector<double> c0(w), c1(w), c2(w);
    for (std::size_t j = small_end; j < ms.size(); ++j) {
      const std::size_t m = ms[j];
      for (std::size_t k0 = 0; k0 < terms(j); k0 += w) {
        const std::size_t len = std::min(w, terms(j) - k0);
        for (auto [at, buf] :
             {std::pair{k0, &c0}, std::pair{k0 + m, &c1}, std::pair{k0 + 2 * m, &c2}}) {
          if (Status st = file.read(at, len, buf->data()); !st) return st.error();
        }
        ss[j].add(allan_detail::cluster_diff_squares(c0.data(), c1.data(), c2.data(), len));
      }
    }
  }
  std::vector<double> var(ms.size());
  for (std::size_t j = 0; j < ms.size(); ++j) {
    const auto m = static_cast<double>(ms[j]);
    var[j] = ss[j].value() / (m * m) / (2.0 * static_cast<double>(terms(j)));
  }
  return var;
}

Error prefixed(const Error& e) {
  Error out = e;
  out.message = "allan_deviation: " + e.message;
  return out;
}

}  // namespace

Result<AllanResult> allan_deviation(const SampleSource& source, const AllanOptions& options,
                                    const StreamLimits& limits) {
  if (std::string why; !options.is_valid(&why)) {
    return Error::Permanent("allan_deviation: invalid options: " + why);
  }
  if (std::string why; !limits.is_valid(&why)) {
    return Error::Permanent("allan_deviation: invalid limits: " + why);
  }
  auto scan = scan_series(source);
  if (!scan) return prefixed(scan.error());
  const std::size_t n = scan->n;
  if (n < 2) {
    return Error::Permanent(fmt::format("allan_deviation: {} sample(s), at least 2 are needed", n));
  }
  const double tau0_s = scan->spacing_lower_s + (scan->spacing_upper_s - scan->spacing_lower_s) / 2;
  const std::vector<std::size_t> ms = allan_cluster_sizes(n, options.taus);
  const bool in_memory = n + 1 <= limits.prefix_in_memory;
  if (!in_memory && options.taus == TauSet::kAll) {
    return Error::Permanent(fmt::format(
        "allan_deviation: tau set 'all' on {} samples (more than {} held in memory) would take "
        "O(N^2); use octave or decade",
        n, limits.prefix_in_memory - 1));
  }

  PrefixSink sink;
  std::optional<allan_detail::ScratchBuffer> memory;
  std::unique_ptr<ScratchFile> file;
  if (in_memory) {
    memory.emplace(n + 1);
    sink.memory = memory->data();
  } else {
    auto f = ScratchFile::create(limits.scratch_dir);
    if (!f) return prefixed(f.error());
    file = std::move(*f);
    sink.file = file.get();
    for (const std::size_t m : ms) {
      if (n / m < kMinNoiseIdAverages) break;
      sink.blocks.push_back({.m = m, .next = m, .last = n / m * m, .c_prev = 0, .id = {}});
    }
  }
  if (Status st = build_prefix(source, n, scan->first_block_mean, sink); !st) {
    return prefixed(st.error());
  }

  std::vector<double> var;
  std::vector<std::optional<NoiseIdentification>> ids(ms.size());
  if (in_memory) {
    if (!std::isfinite(sink.memory[n])) {
      return Error::Permanent("allan_deviation: the rates are too large (their sum overflows)");
    }
    var = allan_detail::allan_variances(sink.memory, n, ms);
    for (std::size_t j = 0; j < ms.size(); ++j) {
      if (n / ms[j] >= kMinNoiseIdAverages) {
        ids[j] = allan_detail::identify_block_means(
            allan_detail::block_means_from_prefix(sink.memory, n, ms[j]));
      }
    }
  } else {
    double last = 0;
    if (Status st = file->read(n, 1, &last); !st) return prefixed(st.error());
    if (!std::isfinite(last)) {
      return Error::Permanent("allan_deviation: the rates are too large (their sum overflows)");
    }
    auto swept = swept_variances(*file, n, ms, limits.window);
    if (!swept) return prefixed(swept.error());
    var = std::move(*swept);
    for (std::size_t j = 0; j < sink.blocks.size(); ++j) ids[j] = sink.blocks[j].id.result();
  }
  return allan_detail::assemble_allan(n, tau0_s, ms, var, ids);
}

}  // namespace gyrotherm::analysis
