#include "server/wire.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "client/localization_client.h"
#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

wire::LocalizeRequest SmallRequest(bool float16, Random& random) {
  std::vector<float> keypoints;
  std::vector<float> descriptors;
  for (int i = 0; i < 10; ++i) {
    keypoints.push_back(static_cast<float>(random.Uniform(1, 600)));
    keypoints.push_back(static_cast<float>(random.Uniform(1, 400)));
    for (int j = 0; j < 8; ++j) descriptors.push_back(static_cast<float>(random.Normal()));
  }
  return MakeLocalizeRequest("q.jpg", ParseCamera("SIMPLE_RADIAL 640 480 500 320 240 0.01"),
                             keypoints, descriptors, 8, float16);
}

TEST(WireTest, Float16DescriptorsDecodeWithinHalfPrecision) {
  Random random(5);
  std::vector<float> descriptors(10 * 8);
  for (float& value : descriptors) value = static_cast<float>(random.Normal());
  const wire::LocalizeRequest request =
      MakeLocalizeRequest("q.jpg", ParseCamera("PINHOLE 640 480 500 500 320 240"),
                          std::vector<float>(20, 10.0f), descriptors, 8, true);
  const LocalizationQuery query = QueryFromWire(request, WireLimits());
  for (size_t i = 0; i < descriptors.size(); ++i) {
    // Round to nearest with 11 significant bits: a relative error of at most 2^-11.
    EXPECT_NEAR(query.descriptors.data()[i], descriptors[i], std::abs(descriptors[i]) / 2048 + 1e-7)
        << i;
  }
}

TEST(WireTest, QueryRoundTripsFromTheClientsPacking) {
  Random random(3);
  for (const bool float16 : {false, true}) {
    const wire::LocalizeRequest request = SmallRequest(float16, random);
    const LocalizationQuery query = QueryFromWire(request, WireLimits());
    EXPECT_EQ(query.name, "q.jpg");
    EXPECT_EQ(query.camera.model_id, CameraModelIdFromName("SIMPLE_RADIAL"));
    ASSERT_EQ(query.keypoints.rows(), 10);
    ASSERT_EQ(query.descriptors.cols(), 8);
    EXPECT_EQ(std::memcmp(query.keypoints.data(), request.keypoints().data(), 80), 0);
    if (!float16) {
      EXPECT_EQ(std::memcmp(query.descriptors.data(), request.descriptors().data(), 320), 0);
    }
    EXPECT_FALSE(query.global_descriptor.has_value());
  }
}

TEST(WireTest, QueryToWireInvertsQueryFromWire) {
  Random random(6);
  LocalizationQuery query;
  query.name = "night/q.jpg";
  query.camera =
      Camera::FromModelName(0, "OPENCV", 640, 480, {500, 501, 320, 240, 0.01, -0.02, 1e-4, 2e-4});
  query.keypoints.resize(25, 2);
  query.descriptors.resize(25, 16);
  for (int64_t i = 0; i < query.keypoints.size(); ++i) {
    query.keypoints.data()[i] = static_cast<float>(random.Uniform(1, 470));
  }
  for (int64_t i = 0; i < query.descriptors.size(); ++i) {
    query.descriptors.data()[i] = static_cast<float>(random.Normal());
  }
  query.global_descriptor = Eigen::VectorXf::Constant(7, 0.25f);
  const LocalizationQuery back = QueryFromWire(QueryToWire(query, false), WireLimits());
  EXPECT_EQ(back.name, query.name);
  EXPECT_EQ(back.camera.params, query.camera.params);
  EXPECT_EQ(back.camera.model_id, query.camera.model_id);
  EXPECT_EQ(back.keypoints, query.keypoints);
  EXPECT_EQ(back.descriptors, query.descriptors);
  ASSERT_TRUE(back.global_descriptor.has_value());
  EXPECT_EQ(*back.global_descriptor, *query.global_descriptor);
  const LocalizationQuery half = QueryFromWire(QueryToWire(query, true), WireLimits());
  EXPECT_TRUE(half.descriptors.isApprox(query.descriptors, 1e-3f));
  EXPECT_NE(half.descriptors, query.descriptors);
}

TEST(WireTest, EveryInconsistentFieldIsNamed) {
  Random random(4);
  const wire::LocalizeRequest good = SmallRequest(false, random);
  const auto message = [&](const std::function<void(wire::LocalizeRequest&)>& corrupt) {
    wire::LocalizeRequest request = good;
    corrupt(request);
    return testing::InvalidArgumentMessage([&] { QueryFromWire(request, WireLimits()); });
  };
  EXPECT_THAT(message([](auto& r) { r.set_num_keypoints(11); }), HasSubstr("keypoints hold 80"));
  EXPECT_THAT(message([](auto& r) { r.set_num_keypoints(20001); }), HasSubstr("limit of 20000"));
  EXPECT_THAT(message([](auto& r) { r.set_descriptor_dim(0); }), HasSubstr("descriptor_dim 0"));
  EXPECT_THAT(message([](auto& r) { r.set_descriptor_dim(7); }), HasSubstr("descriptors hold"));
  EXPECT_THAT(message([](auto& r) { r.set_descriptor_type(static_cast<wire::DescriptorType>(9)); }),
              HasSubstr("descriptor_type 9"));
  EXPECT_THAT(message([](auto& r) { r.mutable_camera()->set_model("NOPE"); }), HasSubstr("camera"));
  EXPECT_THAT(message([](auto& r) { r.mutable_camera()->clear_params(); }), HasSubstr("camera"));

  wire::LocalizeOptions overrides;
  overrides.set_top_k(3);
  overrides.set_exhaustive(false);
  const LocalizerOptions options = OptionsFromWire(overrides, LocalizerOptions(), WireLimits());
  EXPECT_EQ(options.top_k, 3);
  EXPECT_EQ(options.candidate_search, CandidateSearch::kUntilAccepted);
  EXPECT_TRUE(options.visibility_filter);
  overrides.set_top_k(1000);
  EXPECT_THAT(testing::InvalidArgumentMessage(
                  [&] { OptionsFromWire(overrides, LocalizerOptions(), WireLimits()); }),
              HasSubstr("top_k = 1000"));
}

TEST(WireTest, CandidatesCarryTheirRetrievalSource) {
  Scene scene;
  for (const char* name : {"a.jpg", "b.jpg", "c.jpg"}) {
    SceneImage image;
    image.image_id = static_cast<image_t>(scene.images.size() + 1);
    image.name = name;
    scene.images.push_back(image);
  }
  PoseResult result;
  result.candidates.resize(3);
  for (uint32_t k = 0; k < 3; ++k) {
    result.candidates[k].image_index = k;
    result.candidates[k].image_id = k + 1;
  }
  result.candidates[1].source = CandidateSource::kPointVotes;
  result.candidates[2].source = CandidateSource::kNearestPoints;
  result.candidates[1].retrieval_score = 7.5f;
  wire::LocalizeResponse response;
  PoseResultToWire(result, scene, &response);
  ASSERT_EQ(response.candidates_size(), 3);
  EXPECT_EQ(response.candidates(0).source(), wire::GLOBAL_DESCRIPTOR);
  EXPECT_EQ(response.candidates(1).source(), wire::POINT_VOTES);
  EXPECT_EQ(response.candidates(2).source(), wire::NEAREST_POINTS);
  EXPECT_EQ(response.candidates(1).image_name(), "b.jpg");
  EXPECT_FLOAT_EQ(response.candidates(1).retrieval_score(), 7.5f);
}

}  // namespace
}  // namespace hscloc
