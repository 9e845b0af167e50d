#include "util/timer.h"

#include <gtest/gtest.h>

#include <stdexcept>
#include <thread>

namespace hscloc {
namespace {

TEST(Timer, MeasuresNonNegativeMonotonicTime) {
  Timer timer;
  const double first = timer.ElapsedSeconds();
  std::this_thread::sleep_for(std::chrono::milliseconds(2));
  const double second = timer.ElapsedSeconds();
  EXPECT_GE(first, 0.0);
  EXPECT_GT(second, first);
  EXPECT_NEAR(timer.ElapsedMilliseconds(), 1e3 * timer.ElapsedSeconds(), 1.0);
}

TEST(ScopedTimer, AccumulatesEvenWhenTheScopeThrows) {
  double total_ms = 0;
  {
    ScopedTimer timer(&total_ms);
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  const double after_first = total_ms;
  EXPECT_GT(after_first, 0.0);
  // The throwing scope sleeps, so its time is measurable: at least the 2 ms it slept must arrive.
  try {
    ScopedTimer timer(&total_ms);
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
    throw std::runtime_error("stage failed");
  } catch (const std::runtime_error&) {
  }
  EXPECT_GE(total_ms - after_first, 2.0);
}

TEST(FormatDuration, PicksReadableUnits) {
  EXPECT_EQ(FormatDuration(0.85), "850 ms");
  EXPECT_EQ(FormatDuration(12.34), "12.3 s");
  EXPECT_EQ(FormatDuration(245), "4 min 05 s");
  EXPECT_EQ(FormatDuration(7380), "2 h 03 min");
  EXPECT_EQ(FormatDuration(-1), "?");
}

}  // namespace
}  // namespace hscloc
