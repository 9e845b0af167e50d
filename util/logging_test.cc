#include "util/logging.h"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <stdexcept>

namespace hscloc {
namespace {

TEST(LoggingTest, SetupTwiceChangesTheLevelOfOneLogger) {
  SetupLogging("warn");
  const auto first = spdlog::default_logger();
  EXPECT_EQ(first->level(), spdlog::level::warn);
  SetupLogging("debug");
  EXPECT_EQ(spdlog::default_logger(), first);
  EXPECT_EQ(first->level(), spdlog::level::debug);
}

TEST(LoggingTest, UnknownLevelIsAnError) {
  EXPECT_THROW(SetupLogging("loud"), std::invalid_argument);
  EXPECT_NO_THROW(SetupLogging("off"));
}

}  // namespace
}  // namespace hscloc
