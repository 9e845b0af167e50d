#include "util/check.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;
using ::testing::StartsWith;

TEST(Check, PassingChecksDoNotThrow) {
  EXPECT_NO_THROW(THROW_CHECK(1 + 1 == 2));
  EXPECT_NO_THROW(THROW_CHECK_MSG(true, "unused {}", 1));
  EXPECT_NO_THROW(THROW_CHECK_EQ(3, 3));
  EXPECT_NO_THROW(THROW_CHECK_LT(2, 3));
  EXPECT_NO_THROW(THROW_CHECK_GE(3, 3));
}

TEST(Check, FailureNamesFileLineAndCondition) {
  const int line = __LINE__ + 1;
  const std::string message = testing::InvalidArgumentMessage([] { THROW_CHECK(2 < 1); });
  EXPECT_THAT(message, StartsWith("check_test.cc:" + std::to_string(line) + ":"));
  EXPECT_THAT(message, HasSubstr("Check failed: 2 < 1"));
}

TEST(Check, MessageIsFormatted) {
  const std::string message = testing::InvalidArgumentMessage(
      [] { THROW_CHECK_MSG(false, "image '{}' has {} keypoints", "a.jpg", 7); });
  EXPECT_THAT(message, HasSubstr("image 'a.jpg' has 7 keypoints"));
}

TEST(Check, ComparisonShowsBothValues) {
  const int expected = 128;
  const int dimension = 256;
  const std::string message =
      testing::InvalidArgumentMessage([&] { THROW_CHECK_EQ(dimension, expected); });
  EXPECT_THAT(message, HasSubstr("dimension == expected (256 vs. 128)"));
  EXPECT_THAT(testing::InvalidArgumentMessage([] { THROW_CHECK_NE(1, 1); }),
              HasSubstr("(1 vs. 1)"));
  EXPECT_THAT(testing::InvalidArgumentMessage([] { THROW_CHECK_LE(2, 1); }), HasSubstr("2 <= 1"));
  EXPECT_THAT(testing::InvalidArgumentMessage([] { THROW_CHECK_GT(1, 1); }), HasSubstr("1 > 1"));
}

TEST(Check, ArgumentsAreEvaluatedOnce) {
  int calls = 0;
  auto next = [&calls] { return ++calls; };
  THROW_CHECK_EQ(next(), 1);
  EXPECT_EQ(calls, 1);
}

TEST(Check, ThrowInvalidArgumentFormats) {
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [] { ThrowInvalidArgument("{}: bad field '{}'", "cameras.txt", "fx"); }),
              HasSubstr("cameras.txt: bad field 'fx'"));
}

}  // namespace
}  // namespace hscloc
