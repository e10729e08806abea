// The pieces of the overlapping Allan deviation (allan.h) that the in-memory
// path (allan.cpp) and the streamed one (allan_streamed.cpp) share: the
// prefix sums, the sweep kernel, the noise identification and the assembly
// of the result. Private to the analysis library.
#pragma once

#include <cstddef>
#include <cstdlib>
#include <new>
#include <optional>
#include <span>
#include <vector>
#if defined(__linux__)
#include <sys/mman.h>
#endif

#include "compensated_sum.h"
#include "gyrotherm/analysis/allan.h"

namespace gyrotherm::analysis::allan_detail {

// Prefix sums are built kBlock rates at a time, in kLanes interleaved add
// chains (prefix_block).
inline constexpr std::size_t kBlock = 4096;
inline constexpr std::size_t kLanes = 4;

// A large scratch array of doubles. Fresh 4 KiB pages cost a page fault each
// (80 MB: ~20k faults, tens of ms), so on Linux the buffer is 2 MiB aligned
// and transparent huge pages are requested for it.
class ScratchBuffer {
 public:
  explicit ScratchBuffer(std::size_t n) {
    constexpr std::size_t kHuge = std::size_t{2} << 20;
    const std::size_t bytes = (n * sizeof(double) + kHuge - 1) / kHuge * kHuge;
    data_ = static_cast<double*>(std::aligned_alloc(kHuge, bytes));
    if (data_ == nullptr) throw std::bad_alloc();
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    madvise(data_, bytes, MADV_HUGEPAGE);
#endif
  }
  ~ScratchBuffer() { std::free(data_); }
  ScratchBuffer(const ScratchBuffer&) = delete;
  ScratchBuffer& operator=(const ScratchBuffer&) = delete;
  double* data() { return data_; }

 private:
  double* data_ = nullptr;
};

// sum_{i<n} ((c2[i] - c1[i]) - (c1[i] - c0[i]))^2: with c0 = C + k, c1 =
// C + k + m, c2 = C + k + 2m, m^2 times the squared differences of adjacent
// cluster means at offsets k ... k + n - 1. Cloned for AVX2/FMA where
// available.
double cluster_diff_squares(const double* c0, const double* c1, const double* c2, std::size_t n);

// The prefix sums of one block of nb <= kBlock rates y: c[k] = offset +
// sum_{j<=k} (y_j - shift). kLanes local prefix sums run interleaved from 0
// (independent add chains), then each lane gets its offset, a compensated
// running total (advanced past the block): every C[k] is rounded about
// once, so its error stays ~eps |C[k]| however long the series. The shift
// is any value near the mean: a wrong shift adds a linear term to C, which
// the second differences of the Allan variance cancel exactly.
void prefix_block(const double* y, std::size_t nb, double shift, CompensatedSum& offset, double* c);

// The shift of the prefix sums: the mean of the first min(n, kBlock) rates
// (0 when not finite).
double first_block_mean(std::span<const double> y);

// The overlapping Allan variances for the cluster sizes ms (ascending) from
// the prefix sums c[0 .. n] of n rates, in memory.
std::vector<double> allan_variances(const double* c, std::size_t n,
                                    const std::vector<std::size_t>& ms);

// identify_noise_lag1 on the block means x (any common offset: a straight
// line is removed first); and the block means of m rates from prefix sums.
std::optional<NoiseIdentification> identify_block_means(std::vector<double> x);
std::vector<double> block_means_from_prefix(const double* c, std::size_t n, std::size_t m);

// The result from the variances of n rates at tau0_s: per cluster size the
// noise identified there (nullopt: too few block means, or none; the last
// identified one then stands), its edf and 1-sigma bounds, and the noise
// terms read off the curve.
AllanResult assemble_allan(std::size_t n, double tau0_s, const std::vector<std::size_t>& ms,
                           const std::vector<double>& var,
                           const std::vector<std::optional<NoiseIdentification>>& ids);

}  // namespace gyrotherm::analysis::allan_detail
