// The peers of HSC on one query set: the nearest-neighbour baseline on the same bundle and COLMAP's
// image_registrator, which matches each query against every map image.
#pragma once

#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "bench/bench_options.h"
#include "localization/localizer.h"
#include "scene/query_io.h"

namespace hscloc::bench {

// COLMAP's matches_importer and image_registrator for each query of a real set; throws when
// COLMAP is missing or fails.
nlohmann::json RunColmapRegistration(const BenchOptions& options,
                                     const std::filesystem::path& set_dir,
                                     const std::vector<QueryWithIntrinsics>& queries,
                                     const std::vector<NamedPose>& ground_truth);
// The bundle's bytes as HSC serves it (no observation descriptors) and as the nearest-neighbour
// matcher does (no network).
nlohmann::json BundleSizes(const std::filesystem::path& bundle);
// HSC and the nearest-neighbour baseline (and `colmap`, measured apart) on one query set.
nlohmann::json ComparePeers(const std::string& name, const std::filesystem::path& bundle,
                            double train_seconds, const std::vector<LocalizationQuery>& queries,
                            const std::vector<NamedPose>& ground_truth,
                            const nlohmann::json& colmap);
enum class LocalFeature { kSift, kXFeat };
// A real set of the data directory: build-map, then for each training seed 1 .. options.seeds
// train a copy for `train_minutes` (nullopt: `hscloc train`'s own budget for the map, what a user
// gets) and ComparePeers on it. The row is seed 1's, with every seed's matchers under "seeds".
// SIFT: the set's own database and map, and COLMAP's registration beside; XFeat: `hscloc extract`
// on its photos and `hscloc triangulate` from its map's poses first (named "SET, XFeat").
nlohmann::json RealSetPeers(const BenchOptions& options, const std::string& set,
                            LocalFeature feature, std::optional<double> train_minutes);

}  // namespace hscloc::bench
