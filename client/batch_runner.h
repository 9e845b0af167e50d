// The client's batch mode: a query list with its features sent to an hscloc server with several
// requests in flight, written as the same submission `hscloc localize` writes, in query order
// whatever order the replies come in.
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "client/localization_client.h"
#include "proto/hscloc.pb.h"
#include "scene/feature_io.h"
#include "scene/query_io.h"

namespace hscloc {

// A camera in the wire format, through its COLMAP text form (numbers keep full precision).
wire::Camera CameraToWire(const Camera& camera);
// A localize request from one image's features.
wire::LocalizeRequest RequestFromFeatures(const std::string& name, const wire::Camera& camera,
                                          const ImageFeatures& features, bool float16);
// The pose as received: the server sends the unit quaternion it computed as doubles, so it is
// not renormalized, and a submission made through the server is bit for bit the one
// `hscloc localize` writes.
Rigid3d PoseFromWire(const wire::Pose& pose);

struct BatchOptions {
  ClientOptions client;
  // The submission; failures (status and message) go to `<out>.failures.txt`.
  std::filesystem::path out;
  // Requests in flight, one connection each.
  int inflight = 16;
  // Descriptors as float16 (half the bytes; the last bits of results may differ from float32).
  bool float16 = true;
  bool show_progress = true;

  // Throws std::invalid_argument naming the field.
  void Check() const;
};

struct BatchSummary {
  size_t num_queries = 0;
  size_t num_localized = 0;
  // Not localized (still written, with the top-1 retrieved image's pose) or refused (not
  // written); all are listed in failures_path.
  size_t num_failed = 0;
  std::filesystem::path failures_path;
  double seconds = 0;
};

// Localizes every query through the server. Throws std::invalid_argument for bad options or a
// query without features, ClientError when the server does not answer; the first error stops
// the batch.
BatchSummary RunBatch(const std::vector<QueryWithIntrinsics>& queries,
                      const FeatureReader& features, const BatchOptions& options);

}  // namespace hscloc
