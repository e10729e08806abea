// CoverageSpans: the stretches a stream's samples cover, gaps and all.
#include "gyrotherm/schedules/coverage.h"

#include <gtest/gtest.h>

namespace gyrotherm::schedules {
namespace {

constexpr double kTol = 1e-9;

TEST(CoverageSpansTest, EmptyCoversNothing) {
  CoverageSpans c(0.1);
  EXPECT_EQ(c.covered_s(0, 100), 0.0);
  EXPECT_FALSE(c.reached_at(0, 1).has_value());
  EXPECT_FALSE(c.end_s().has_value());
  EXPECT_EQ(*c.reached_at(3.0, 0.0), 3.0);
}

TEST(CoverageSpansTest, AnUnbrokenStreamCoversItsSamplesPeriods) {
  CoverageSpans c(0.1);
  for (int i = 0; i < 100; ++i) c.add(10.0 + i * 0.1);  // 10.0 .. 19.9
  EXPECT_NEAR(c.covered_s(0, 100), 10.0, kTol);
  EXPECT_NEAR(c.covered_s(12, 13), 1.0, kTol);
  EXPECT_NEAR(*c.end_s(), 20.0, kTol);
  EXPECT_NEAR(*c.reached_at(10.0, 4.0), 14.0, kTol);
  EXPECT_EQ(c.spans(), 1U);
}

TEST(CoverageSpansTest, OneMissingSampleIsBridgedALongerGapIsNot) {
  CoverageSpans c(1.0);
  c.add(0);
  c.add(1);
  c.add(3);  // one sample (2) missing: bridged
  EXPECT_NEAR(c.covered_s(0, 10), 4.0, kTol);
  c.add(7);  // 4, 5, 6 missing: a gap [4, 7)
  c.add(8);
  EXPECT_NEAR(c.covered_s(0, 10), 6.0, kTol);
  EXPECT_NEAR(c.covered_s(4, 7), 0.0, kTol);
  EXPECT_EQ(c.spans(), 2U);
  // Six covered seconds from 0 are reached at 9 (the end of sample 8).
  EXPECT_NEAR(*c.reached_at(0, 6.0), 9.0, kTol);
  EXPECT_NEAR(*c.reached_at(0, 4.5), 7.5, kTol);  // the gap is not counted
  EXPECT_FALSE(c.reached_at(0, 6.5).has_value());
}

TEST(CoverageSpansTest, ASampleOutOfOrderIsIgnored) {
  CoverageSpans c(1.0);
  c.add(5);
  c.add(6);
  c.add(2);
  EXPECT_NEAR(c.covered_s(0, 10), 2.0, kTol);
}

TEST(CoverageSpansTest, ForgetKeepsTheSpanInProgress) {
  CoverageSpans c(1.0);
  c.add(0);
  c.add(10);
  c.add(20);
  EXPECT_EQ(c.spans(), 3U);
  c.forget_before(15);
  EXPECT_EQ(c.spans(), 1U);
  EXPECT_NEAR(c.covered_s(0, 30), 1.0, kTol);
  c.forget_before(100);  // the last span stays: the next sample extends it
  EXPECT_EQ(c.spans(), 1U);
  c.add(21);
  EXPECT_NEAR(c.covered_s(0, 30), 2.0, kTol);
}

}  // namespace
}  // namespace gyrotherm::schedules
