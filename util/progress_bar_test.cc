#include "util/progress_bar.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <thread>
#include <vector>

namespace hscloc {
namespace {

using ::testing::AnyOf;
using ::testing::HasSubstr;
using ::testing::Not;

TEST(ProgressBar, CountsFromManyThreads) {
  ProgressBar bar("work", 8000, ProgressBar::Display::kNever);
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&bar] {
      for (int i = 0; i < 2000; ++i) bar.Advance();
    });
  }
  for (auto& thread : threads) thread.join();
  EXPECT_EQ(bar.done(), 8000u);
  EXPECT_THAT(bar.Render(), HasSubstr("100%"));
}

TEST(ProgressBar, RendersPercentEtaAndStatus) {
  ProgressBar bar("train", 200, ProgressBar::Display::kNever);
  bar.Advance(50);
  bar.SetStatus("loss 0.42");
  const std::string line = bar.Render();
  EXPECT_THAT(line, HasSubstr("train ["));
  EXPECT_THAT(line, HasSubstr(" 25% 50/200"));
  EXPECT_THAT(line, HasSubstr("ETA"));
  EXPECT_THAT(line, HasSubstr("loss 0.42"));
}

TEST(ProgressBar, ATimeLimitGivesPercentAndEtaWithoutATotal) {
  ProgressBar bar("train", 0, ProgressBar::Display::kNever);
  bar.Advance(3);
  bar.SetTimeLimit(600);
  const std::string line = bar.Render();
  EXPECT_THAT(line, HasSubstr("train ["));
  EXPECT_THAT(line, HasSubstr("  0% 3 "));
  EXPECT_THAT(line, AnyOf(HasSubstr("ETA 9 min 59 s"), HasSubstr("ETA 10 min 00 s")));
}

TEST(ProgressBar, TheEarlierOfUnitsAndTimeLimitSetsTheEta) {
  ProgressBar bar("train", 1000000, ProgressBar::Display::kNever);
  bar.Advance(1);
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  // At this rate the units would take hours; the 10 minutes end the work first.
  bar.SetTimeLimit(600);
  EXPECT_THAT(bar.Render(), AnyOf(HasSubstr("ETA 9 min 59 s"), HasSubstr("ETA 10 min 00 s")));
  EXPECT_THAT(bar.Render(), HasSubstr("1/1.00M"));
  // Without it, the units' ETA stands.
  bar.SetTimeLimit(0);
  EXPECT_THAT(bar.Render(), Not(HasSubstr("ETA 9 min")));
}

TEST(ProgressBar, UnknownTotalShowsCountOnly) {
  ProgressBar bar("scan", 0, ProgressBar::Display::kNever);
  bar.Advance(12);
  EXPECT_THAT(bar.Render(), Not(HasSubstr("%")));
  EXPECT_THAT(bar.Render(), HasSubstr("scan 12"));
}

TEST(ProgressBar, DoesNotDrawWhenNotAskedTo) {
  ProgressBar bar("quiet", 10, ProgressBar::Display::kNever);
  EXPECT_FALSE(bar.drawing());
  ::testing::internal::CaptureStderr();
  bar.Advance(10);
  bar.Finish();
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
}

TEST(ProgressBar, LogsPlainLinesWithoutATerminal) {
  if (isatty(fileno(stderr))) GTEST_SKIP() << "stderr is a terminal here";
  ::testing::internal::CaptureStderr();
  {
    ProgressBar bar("batch", 5, ProgressBar::Display::kAuto);
    EXPECT_TRUE(bar.drawing());
    bar.Advance(5);  // within the first 15 s: no line yet
    bar.Finish();
  }
  const std::string output = ::testing::internal::GetCapturedStderr();
  EXPECT_THAT(output, HasSubstr("batch ["));
  EXPECT_THAT(output, HasSubstr("100% 5/5"));
  EXPECT_THAT(output, Not(HasSubstr("\r")));
  EXPECT_EQ(std::count(output.begin(), output.end(), '\n'), 1);
}

TEST(ProgressBar, DrawsFinalLineOnce) {
  ::testing::internal::CaptureStderr();
  {
    ProgressBar bar("loud", 3, ProgressBar::Display::kAlways);
    bar.Advance(3);
    bar.Finish();
  }
  const std::string output = ::testing::internal::GetCapturedStderr();
  EXPECT_THAT(output, HasSubstr("loud ["));
  EXPECT_EQ(std::count(output.begin(), output.end(), '\n'), 1);
}

}  // namespace
}  // namespace hscloc
