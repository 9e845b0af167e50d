// Which matcher a map localizes with when asked for "auto". The network exists to be the cheaper
// way to match at scale, but on a map of a few thousand points its levels cost more than matching
// every keypoint against the retrieved images' observations. `hscloc train` times both matchers on
// the map it has just trained and records the result in the bundle; "auto" reads that record.
#pragma once

#include <nlohmann/json.hpp>
#include <optional>

#include "localization/localization_map.h"
#include "localization/localizer.h"
#include "model/network.h"

namespace hscloc {

// The match stage of both matchers on one probe: `keypoints` of the map's own observation
// descriptors against `images` database images, on one thread, the fastest of a few runs each.
struct MatchingCost {
  int keypoints = 0;
  int images = 0;
  double network_ms = 0;
  double nearest_neighbor_ms = 0;

  // The matcher with the lower time; the network on a tie.
  Matcher Cheaper() const;
  nlohmann::json ToJson() const;
  // ToJson() under the key FromMetadata reads, for WriteNetworkToBundle's notes.
  nlohmann::json AsNetworkNotes() const;
  // The record in a bundle's metadata (under "network"), or nullopt where the bundle has none or a
  // malformed one.
  static std::optional<MatchingCost> FromMetadata(const nlohmann::json& metadata);
};

// Times the match stage of `network` and of nearest-neighbour matching on one probe, each as the
// Localizer runs it with `options`: the probe's descriptors are spread over the map's
// observations (the map must hold them) and its images over the map's images. On one thread of
// the CPU, as a query runs (`network` must be on the CPU); the compute threads are restored after.
MatchingCost MeasureMatchingCost(const LocalizationMap& map, const Network& network,
                                 const LocalizerOptions& options = {}, int keypoints = 1000,
                                 int images = 10);

// What `requested` means on a map with this metadata: kAuto becomes the recorded cheaper matcher
// when the map can run it, else the network when it has one, else nearest neighbour; the other
// matchers are returned as they are.
Matcher ResolveMatcher(Matcher requested, const nlohmann::json& metadata, bool has_network,
                       bool has_observations);

// One line for a user: which matcher "auto" runs on a map with this record (or none) and why.
std::string DescribeAutoMatcher(const std::optional<MatchingCost>& cost, bool has_network,
                                bool has_observations);

// "matcher hsc" for an explicit matcher; for kAuto, which one the localizer's map runs and why.
std::string DescribeMatcher(const Localizer& localizer, Matcher requested);

}  // namespace hscloc
