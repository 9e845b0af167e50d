#include "server/wire.h"

#include <cstring>

#include "util/check.h"
#include "util/half.h"

namespace hscloc {
namespace {

void ToWire(const Rigid3d& cam_from_world, wire::Pose* pose) {
  pose->set_qw(cam_from_world.rotation.w());
  pose->set_qx(cam_from_world.rotation.x());
  pose->set_qy(cam_from_world.rotation.y());
  pose->set_qz(cam_from_world.rotation.z());
  pose->set_tx(cam_from_world.translation.x());
  pose->set_ty(cam_from_world.translation.y());
  pose->set_tz(cam_from_world.translation.z());
}

// Packed little-endian float32 values; this build targets little-endian machines only (checked
// at compile time), so the bytes are copied as they are.
static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "the wire format is little-endian");

wire::CandidateSource WireSource(CandidateSource source) {
  switch (source) {
    case CandidateSource::kGlobalDescriptor:
      return wire::GLOBAL_DESCRIPTOR;
    case CandidateSource::kPointVotes:
      return wire::POINT_VOTES;
    case CandidateSource::kNearestPoints:
      return wire::NEAREST_POINTS;
  }
  ThrowInvalidArgument("unknown candidate source {}", static_cast<int>(source));
}

}  // namespace

LocalizationQuery QueryFromWire(const wire::LocalizeRequest& request, const WireLimits& limits) {
  const std::string name =
      request.query_name().empty() ? "request " + request.request_id() : request.query_name();
  const uint64_t n = request.num_keypoints();
  const uint64_t d = request.descriptor_dim();
  if (n > limits.max_keypoints) {
    ThrowInvalidArgument("{}: num_keypoints {} exceeds the server's limit of {}", name, n,
                         limits.max_keypoints);
  }
  if (d == 0 || d > limits.max_descriptor_dim) {
    ThrowInvalidArgument("{}: descriptor_dim {} outside 1 .. {}", name, d,
                         limits.max_descriptor_dim);
  }
  if (request.keypoints().size() != n * 2 * sizeof(float)) {
    ThrowInvalidArgument("{}: keypoints hold {} bytes, expected N x 2 float32 = {}", name,
                         request.keypoints().size(), n * 2 * sizeof(float));
  }
  size_t value_bytes = 0;
  switch (request.descriptor_type()) {
    case wire::DESCRIPTOR_FLOAT32:
      value_bytes = 4;
      break;
    case wire::DESCRIPTOR_FLOAT16:
      value_bytes = 2;
      break;
    default:
      ThrowInvalidArgument("{}: unknown descriptor_type {}", name,
                           static_cast<int>(request.descriptor_type()));
  }
  if (request.descriptors().size() != n * d * value_bytes) {
    ThrowInvalidArgument("{}: descriptors hold {} bytes, expected N x D x {} = {}", name,
                         request.descriptors().size(), value_bytes, n * d * value_bytes);
  }
  LocalizationQuery query;
  query.name = name;
  const wire::Camera& camera = request.camera();
  try {
    query.camera =
        Camera::FromModelName(0, camera.model(), camera.width(), camera.height(),
                              std::vector<double>(camera.params().begin(), camera.params().end()));
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: camera: {}", name, error.what());
  }
  query.keypoints.resize(static_cast<int64_t>(n), 2);
  std::memcpy(query.keypoints.data(), request.keypoints().data(), request.keypoints().size());
  query.descriptors.resize(static_cast<int64_t>(n), static_cast<int64_t>(d));
  if (value_bytes == 4) {
    std::memcpy(query.descriptors.data(), request.descriptors().data(),
                request.descriptors().size());
  } else {
    const char* bytes = request.descriptors().data();
    float* values = query.descriptors.data();
    for (uint64_t i = 0; i < n * d; ++i) {
      uint16_t bits;
      std::memcpy(&bits, bytes + 2 * i, 2);
      values[i] = HalfBitsToFloat(bits);
    }
  }
  if (request.global_descriptor_size() > 0) {
    query.global_descriptor = Eigen::Map<const Eigen::VectorXf>(request.global_descriptor().data(),
                                                                request.global_descriptor_size());
  }
  return query;
}

wire::LocalizeRequest QueryToWire(const LocalizationQuery& query, bool float16) {
  THROW_CHECK_EQ(query.keypoints.rows(), query.descriptors.rows());
  wire::LocalizeRequest request;
  request.set_request_id(query.name);
  request.set_query_name(query.name);
  wire::Camera* camera = request.mutable_camera();
  camera->set_model(CameraModelName(query.camera.model_id));
  camera->set_width(static_cast<uint32_t>(query.camera.width));
  camera->set_height(static_cast<uint32_t>(query.camera.height));
  for (const double param : query.camera.params) camera->add_params(param);
  const int64_t n = query.keypoints.rows();
  const int64_t d = query.descriptors.cols();
  request.set_num_keypoints(static_cast<uint32_t>(n));
  request.set_keypoints(query.keypoints.data(), n * 2 * sizeof(float));
  request.set_descriptor_dim(static_cast<uint32_t>(d));
  if (float16) {
    std::string packed(n * d * 2, '\0');
    for (int64_t i = 0; i < n * d; ++i) {
      const uint16_t bits = FloatToHalfBits(query.descriptors.data()[i]);
      std::memcpy(packed.data() + 2 * i, &bits, 2);
    }
    request.set_descriptor_type(wire::DESCRIPTOR_FLOAT16);
    request.set_descriptors(std::move(packed));
  } else {
    request.set_descriptor_type(wire::DESCRIPTOR_FLOAT32);
    request.set_descriptors(query.descriptors.data(), n * d * sizeof(float));
  }
  if (query.global_descriptor.has_value()) {
    for (const float value : *query.global_descriptor) request.add_global_descriptor(value);
  }
  return request;
}

LocalizerOptions OptionsFromWire(const wire::LocalizeOptions& overrides, LocalizerOptions options,
                                 const WireLimits& limits) {
  if (overrides.has_top_k()) {
    if (overrides.top_k() < 1 || overrides.top_k() > limits.max_top_k) {
      ThrowInvalidArgument("options.top_k = {} outside 1 .. {}", overrides.top_k(),
                           limits.max_top_k);
    }
    options.top_k = static_cast<int>(overrides.top_k());
  }
  if (overrides.has_visibility_filter()) options.visibility_filter = overrides.visibility_filter();
  if (overrides.has_exhaustive()) {
    options.candidate_search =
        overrides.exhaustive() ? CandidateSearch::kAll : CandidateSearch::kUntilAccepted;
  }
  return options;
}

void PoseResultToWire(const PoseResult& result, const Scene& scene,
                      wire::LocalizeResponse* response) {
  response->set_status(result.success ? wire::OK : wire::NOT_LOCALIZED);
  response->set_error_message(result.failure_reason);
  if (result.success || !result.candidates.empty()) {
    ToWire(result.cam_from_world, response->mutable_cam_from_world());
  }
  response->set_num_inliers(static_cast<uint32_t>(result.num_inliers));
  const int chosen =
      result.best_candidate >= 0 ? result.best_candidate : (result.candidates.empty() ? -1 : 0);
  if (chosen >= 0) {
    const LocalizationCandidate& candidate = result.candidates[chosen];
    response->set_retrieved_image_id(candidate.image_id);
    response->set_retrieved_image_name(scene.images[candidate.image_index].name);
  }
  for (const LocalizationCandidate& candidate : result.candidates) {
    wire::Candidate* out = response->add_candidates();
    out->set_image_id(candidate.image_id);
    out->set_image_name(scene.images[candidate.image_index].name);
    out->set_retrieval_score(candidate.retrieval_score);
    out->set_num_matches(static_cast<uint32_t>(candidate.num_matches));
    out->set_num_inliers(static_cast<uint32_t>(candidate.num_inliers));
    out->set_evaluated(candidate.evaluated);
    out->set_source(WireSource(candidate.source));
  }
  wire::StageTimings* timings = response->mutable_timings();
  timings->set_retrieval_ms(result.timings.retrieval_ms);
  timings->set_match_ms(result.timings.match_ms);
  timings->set_visibility_ms(result.timings.visibility_ms);
  timings->set_pose_ms(result.timings.pose_ms);
  timings->set_total_ms(result.timings.total_ms);
  timings->set_votes_ms(result.timings.votes_ms);
  timings->set_refine_ms(result.timings.refine_ms);
  timings->set_rounds(static_cast<uint32_t>(result.timings.rounds));
}

std::string StatusName(wire::Status status) { return wire::Status_Name(status); }

}  // namespace hscloc
