// When an adaptive soak has acquired enough: the noise model of the data so
// far (noise_model.h) projects the uncertainty of the soak's mean for any
// length T, and the soak ends once the projection at the length acquired
// reaches the target, or once no length up to the cap would (docs/analysis.md,
// "Adaptive soaks").
//
// Target: the expanded uncertainty at 95 %, U95(T) = k u(T), in °/h, the
// figure Table I shows as "± U95". u(T) comes from mean_uncertainty at T; the
// projection beyond the length acquired keeps the model's coefficients and
// their covariance (more data would narrow them: the projection is on the
// safe side).
//
// Verdicts, judged on the data acquired so far (acquired_s, the covered
// seconds of the soak's windows):
//   - kReached: U95(acquired_s) <= target.
//   - kOutOfReach: the smallest U95(T) over T in [acquired_s, max_s] is above
//     the target, U95(acquired_s) is within kFlatRatio of it (going on
//     would gain at most that ratio), and the term in the way, the flicker
//     floor (sqrt(q_b), k times for U95) or the rate random walk, is there
//     beyond doubt (kOutOfReachZ), and white noise with a wandering bias
//     that has not turned yet (at any correlation time the curve cannot
//     rule out) fits clearly worse or does not reach the target within the
//     cap either; the note says which, with the floor.
//     Flat on a doubtful term: kContinue, the note says so.
//   - kContinue: otherwise; reach_s is the shortest T <= max_s at which the
//     projected U95 reaches the target, nullopt when none does.
//   - kNoModel: the data give no noise model yet (fewer than 8 points, a
//     constant series); the note says why.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "gyrotherm/analysis/noise_model.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm::analysis {

struct AcquisitionTarget {
  double target_u95_dph = 0;  // > 0
  double min_s = 0;           // the soak acquires at least this (>= 0)
  double max_s = 0;           // and at most this (the cap, >= min_s, > 0)

  // False with a message naming the field when a value is out of range.
  bool is_valid(std::string* why) const;
};

enum class AcquisitionVerdict { kContinue, kReached, kOutOfReach, kNoModel };
std::string_view to_string(AcquisitionVerdict v);  // continue, reached, out_of_reach, no_model

// Going on must promise to lower U95 by more than this factor, or a target
// out of reach ends the soak.
inline constexpr double kFlatRatio = 1.1;
// ... and the term in the way (flicker or random walk) must stand this many
// of its standard uncertainties above 0 (two-sided 99.9 %). The covariance
// of the fit ignores the correlation of the overlapping Allan points and is
// too narrow: at 1.96 (95 %), 14 of 400 white-noise axes of 14 min were
// called out of reach on a chance term; at 3.29 none
// (AcquisitionTarget.AWhiteNoiseAxisIsNotCalledOutOfReachOnAChanceTerm).
inline constexpr double kOutOfReachZ = 3.29;

struct AcquisitionProjection {
  AcquisitionVerdict verdict = AcquisitionVerdict::kNoModel;
  double acquired_s = 0;
  std::optional<NoiseModel> model;
  std::optional<MeanUncertainty> now;  // u at acquired_s
  std::optional<double> reach_s;       // kContinue: projected length reaching the target
  double best_u95_dph = 0;             // smallest projected U95 up to max_s
  double floor_u95_dph = 0;            // k x the flicker floor at acquired_s
  std::string note;                    // one line for a technician
};

// Projects the 1 s (or any evenly spaced) bins of the soak so far: t_s their
// times, rate_dph their means; acquired_s the seconds they cover. Errors
// (permanent): an invalid target, sizes that differ, acquired_s not finite
// and > 0.
Result<AcquisitionProjection> project_acquisition(std::span<const double> t_s,
                                                  std::span<const double> rate_dph,
                                                  double acquired_s,
                                                  const AcquisitionTarget& target);

}  // namespace gyrotherm::analysis
