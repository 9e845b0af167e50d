#include "scene/descriptor_bank.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <fstream>

#include "scene/descriptor_bank_test_support.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

DescriptorBank RandomBank(int tracks, int dim, uint64_t seed, const std::string& source) {
  return testing::RandomDescriptorBank(tracks, dim, seed, 1, source);
}

TEST(DescriptorBankTest, RoundTripsThroughItsFile) {
  const DescriptorBank bank = RandomBank(50, 16, 1, "lund");
  testing::TempDir temp;
  bank.Save(temp / "bank.bin");
  const DescriptorBank loaded = DescriptorBank::Load(temp / "bank.bin");
  EXPECT_EQ(loaded, bank);
  EXPECT_EQ(loaded.NumTracks(), 50u);
  EXPECT_EQ(loaded.NumNightViews(), bank.NumViews() - (bank.NumViews() + 2) / 3);
  EXPECT_FALSE(std::filesystem::exists(temp / "bank.bin.partial"));
}

TEST(DescriptorBankTest, ConcatenationKeepsEveryTrackAndItsViews) {
  const DescriptorBank a = RandomBank(7, 8, 2, "a");
  const DescriptorBank b = RandomBank(5, 8, 3, "b");
  const DescriptorBank both = DescriptorBank::Concatenate({a, b});
  ASSERT_EQ(both.NumTracks(), 12u);
  EXPECT_EQ(both.sources(), (std::vector<std::string>{"a", "b"}));
  for (size_t t = 0; t < 5; ++t) {
    const uint32_t first = both.FirstView(7 + t);
    ASSERT_EQ(both.EndView(7 + t) - first, b.EndView(t) - b.FirstView(t));
    for (uint32_t v = 0; v < b.EndView(t) - b.FirstView(t); ++v) {
      EXPECT_EQ(both.day().row(first + v), b.day().row(b.FirstView(t) + v));
      EXPECT_EQ(both.HasNight(first + v), b.HasNight(b.FirstView(t) + v));
    }
  }
  EXPECT_THROW(DescriptorBank::Concatenate({a, RandomBank(3, 16, 4, "c")}), std::invalid_argument);
}

TEST(DescriptorBankTest, NearestViewIsTheViewAtTheSameRelativeOffset) {
  const DescriptorBank bank = RandomBank(30, 4, 5, "s");
  for (size_t t = 0; t < bank.NumTracks(); ++t) {
    const float spread = bank.TrackSpread(t);
    for (uint32_t v = bank.FirstView(t); v < bank.EndView(t); ++v) {
      const Eigen::Vector2f offset = RelativeViewOffset(bank.directions().row(v), spread);
      const uint32_t nearest = bank.NearestView(t, offset);
      // Its own offset, or another view's that is exactly as near.
      EXPECT_LT((RelativeViewOffset(bank.directions().row(nearest), spread) - offset).norm(),
                1e-5f);
    }
  }
  // Offsets scaled by the spread: a set of views twice as wide meets the same views.
  const Eigen::Vector3f narrow = Eigen::Vector3f(0.05f, 0.02f, 1).normalized();
  const Eigen::Vector3f wide = Eigen::Vector3f(0.1f, 0.04f, 1).normalized();
  EXPECT_LT((RelativeViewOffset(narrow, 0.05f) - RelativeViewOffset(wide, 0.1f)).norm(), 0.02f);
  // The spread of unit directions from their sum: none for equal ones, 1 for opposite ones.
  EXPECT_NEAR(DirectionSpread(Eigen::Vector3d(0, 0, 3), 3), 0.0f, 1e-6f);
  EXPECT_NEAR(DirectionSpread(Eigen::Vector3d::Zero(), 2), 1.0f, 1e-6f);
}

TEST(DescriptorBankTest, LocalDirectionsCompareAcrossFrames) {
  // The same view geometry in two frames rotated against each other gives the same local
  // direction: the frame is the reference's and the up's.
  const Eigen::Vector3d reference(0.2, -1, 0.1), up(0, 0, 1), direction(0.5, -1, 0.3);
  const Eigen::Matrix3d rotation =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3f local = LocalViewDirection(direction, reference, up);
  const Eigen::Vector3f rotated =
      LocalViewDirection(rotation * direction, rotation * reference, rotation * up);
  EXPECT_LT((local - rotated).norm(), 1e-6f);
  EXPECT_NEAR(local.norm(), 1.0f, 1e-6f);
  // Along the reference: +z; upward of it: +y.
  EXPECT_GT(LocalViewDirection(reference, reference, up).z(), 0.999f);
  EXPECT_GT(
      LocalViewDirection(reference.normalized() + Eigen::Vector3d(0, 0, 0.3), reference, up).y(),
      0.1f);
}

TEST(DescriptorBankTest, BadFilesAndPartsAreNamed) {
  testing::TempDir temp;
  EXPECT_THAT([&] { DescriptorBank::Load(temp / "missing.bin"); },
              ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr("missing.bin")));
  std::ofstream(temp / "other.bin") << "not a bank at all";
  EXPECT_THAT([&] { DescriptorBank::Load(temp / "other.bin"); },
              ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr("not a descriptor bank")));
  // A truncated bank names the part it lacks.
  RandomBank(10, 8, 6, "t").Save(temp / "bank.bin");
  std::filesystem::resize_file(temp / "bank.bin",
                               std::filesystem::file_size(temp / "bank.bin") - 9);
  EXPECT_THAT([&] { DescriptorBank::Load(temp / "bank.bin"); },
              ::testing::ThrowsMessage<std::invalid_argument>(HasSubstr("truncated")));
  // Parts that disagree.
  const DescriptorBank good = RandomBank(3, 8, 7, "g");
  EXPECT_THROW(DescriptorBank("xfeat", {}, {0, 2, 1}, good.day(), good.directions(), good.night(),
                              std::vector<uint8_t>(good.NumViews())),
               std::invalid_argument);
  DescriptorMatrix not_unit = good.day();
  not_unit.row(0) *= 2;
  EXPECT_THROW(
      DescriptorBank("xfeat", {}, {0, static_cast<uint32_t>(good.NumViews())}, not_unit,
                     good.directions(), good.night(), std::vector<uint8_t>(good.NumViews())),
      std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
