// Conversions between the wire format (proto/hscloc.proto) and the Localizer's types, with the
// checks a server applies to every field before any work is done.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>

#include "localization/localizer.h"
#include "proto/hscloc.pb.h"

namespace hscloc {

// Major version of the protocol; a request of another version is refused with a clear message.
inline constexpr uint32_t kProtocolVersion = 1;
// The server's release, reported in every response.
inline constexpr char kServerVersion[] = "hscloc 0.1.0";

struct WireLimits {
  uint32_t max_keypoints = 20000;
  uint32_t max_descriptor_dim = 4096;
  uint32_t max_top_k = 100;
};

// The query of a request, after checking the fields the Localizer cannot see: sizes of the packed
// arrays against N and D, N and D within the limits, the descriptor type, a known camera model
// with the right parameter count. Throws std::invalid_argument naming the field; the Localizer
// then checks values (finite, inside the image, D equal to the map's).
LocalizationQuery QueryFromWire(const wire::LocalizeRequest& request, const WireLimits& limits);

// The inverse of QueryFromWire, for in-process callers that speak the protocol (tests,
// benchmarks): camera, keypoints and descriptors (float16 when `float16`) and the global
// descriptor when the query has one. The request id is the query's name.
wire::LocalizeRequest QueryToWire(const LocalizationQuery& query, bool float16);

// The server's options with the request's overrides applied (top_k within limits).
LocalizerOptions OptionsFromWire(const wire::LocalizeOptions& overrides, LocalizerOptions options,
                                 const WireLimits& limits);

// Fills status, pose, inliers, retrieved image, candidates and timings.
void PoseResultToWire(const PoseResult& result, const Scene& scene,
                      wire::LocalizeResponse* response);

std::string StatusName(wire::Status status);

}  // namespace hscloc
