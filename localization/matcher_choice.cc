#include "localization/matcher_choice.h"

#include <fmt/format.h>

#include <algorithm>
#include <limits>

#include "localization/nearest_neighbor_matcher.h"
#include "map/map_blobs.h"
#include "model/network.h"
#include "util/check.h"
#include "util/timer.h"

namespace hscloc {
namespace {

constexpr char kMatchingCost[] = "matching_cost";
constexpr int kRuns = 3;  // per matcher, interleaved; the fastest counts

// `count` observation descriptors spread evenly over the map's observations.
DescriptorMatrix ProbeDescriptors(const Scene& scene, int count) {
  const int64_t observations = static_cast<int64_t>(scene.NumObservations());
  const int64_t rows = std::min<int64_t>(count, observations);
  DescriptorMatrix probe(rows, scene.Dimension());
  for (int64_t row = 0; row < rows; ++row) {
    probe.row(row) = scene.observation_descriptors.row(row * observations / rows);
  }
  return probe;
}

// `count` image indices spread evenly over the map's images.
std::vector<uint32_t> ProbeImages(const Scene& scene, int count) {
  const size_t images = scene.NumImages();
  const size_t used = std::min<size_t>(static_cast<size_t>(count), images);
  std::vector<uint32_t> indices;
  for (size_t i = 0; i < used; ++i) indices.push_back(static_cast<uint32_t>(i * images / used));
  return indices;
}

// Predict's kernels on one thread while in scope, as a query runs them.
class OneComputeThread {
 public:
  OneComputeThread() : previous_(ComputeThreads()) { SetComputeThreads(1); }
  ~OneComputeThread() { SetComputeThreads(previous_); }
  OneComputeThread(const OneComputeThread&) = delete;
  OneComputeThread& operator=(const OneComputeThread&) = delete;

 private:
  int previous_;
};

// The scene's images with the observations of `images` only.
Scene ObservationsOf(const Scene& scene, const std::vector<uint32_t>& images) {
  Scene part;
  part.images = scene.images;
  std::vector<char> wanted(scene.NumImages(), 0);
  for (const uint32_t image : images) wanted[image] = 1;
  std::vector<uint32_t> rows;
  for (uint32_t observation = 0; observation < scene.NumObservations(); ++observation) {
    if (wanted[scene.observation_image_indices[observation]]) rows.push_back(observation);
  }
  part.observation_descriptors.resize(static_cast<int64_t>(rows.size()), scene.Dimension());
  for (size_t i = 0; i < rows.size(); ++i) {
    part.observation_image_indices.push_back(scene.observation_image_indices[rows[i]]);
    part.observation_point_indices.push_back(scene.observation_point_indices[rows[i]]);
    part.observation_descriptors.row(static_cast<int64_t>(i)) =
        scene.observation_descriptors.row(rows[i]);
  }
  return part;
}

Matcher AutoMatcher(const std::optional<MatchingCost>& cost, bool has_network,
                    bool has_observations) {
  if (cost.has_value() && has_network && has_observations) return cost->Cheaper();
  return has_network ? Matcher::kNetwork : Matcher::kNearestNeighbor;
}

}  // namespace

Matcher MatchingCost::Cheaper() const {
  return nearest_neighbor_ms < network_ms ? Matcher::kNearestNeighbor : Matcher::kNetwork;
}

nlohmann::json MatchingCost::ToJson() const {
  return {{"keypoints", keypoints},
          {"images", images},
          {"network_ms", network_ms},
          {"nearest_neighbor_ms", nearest_neighbor_ms},
          {"cheaper", MatcherName(Cheaper())}};
}

nlohmann::json MatchingCost::AsNetworkNotes() const { return {{kMatchingCost, ToJson()}}; }

std::optional<MatchingCost> MatchingCost::FromMetadata(const nlohmann::json& metadata) {
  const auto network = metadata.find(map_metadata::kNetwork);
  if (network == metadata.end() || !network->is_object()) return std::nullopt;
  const auto record = network->find(kMatchingCost);
  if (record == network->end() || !record->is_object()) return std::nullopt;
  MatchingCost cost;
  try {
    cost.keypoints = record->at("keypoints").get<int>();
    cost.images = record->at("images").get<int>();
    cost.network_ms = record->at("network_ms").get<double>();
    cost.nearest_neighbor_ms = record->at("nearest_neighbor_ms").get<double>();
  } catch (const nlohmann::json::exception&) {
    return std::nullopt;
  }
  if (!(cost.network_ms >= 0) || !(cost.nearest_neighbor_ms >= 0)) return std::nullopt;
  return cost;
}

MatchingCost MeasureMatchingCost(const LocalizationMap& map, const Network& network,
                                 const LocalizerOptions& options, int keypoints, int images) {
  THROW_CHECK_MSG(keypoints > 0 && images > 0, "MeasureMatchingCost: {} keypoints, {} images",
                  keypoints, images);
  if (network.device() != ComputeDevice::kCpu) {
    ThrowInvalidArgument("timing the network as a query runs needs it on the CPU, not on {}",
                         ComputeDeviceName(network.device()));
  }
  const Scene& scene = map.scene();
  if (scene.NumObservations() == 0) {
    ThrowInvalidArgument("{}: timing nearest-neighbour matching needs the map's observations",
                         map.dir().string());
  }
  const DescriptorMatrix probe = ProbeDescriptors(scene, keypoints);
  const std::vector<uint32_t> probe_images = ProbeImages(scene, images);
  // Nearest neighbour's work per image depends on that image's observations only.
  const NearestNeighborMatcher nearest_neighbor(ObservationsOf(scene, probe_images));
  const bool masked = options.visibility_masked_decoding || network.options().masked_decoding;
  const OneComputeThread one_thread;
  MatchingCost cost;
  cost.keypoints = static_cast<int>(probe.rows());
  cost.images = static_cast<int>(probe_images.size());
  cost.network_ms = std::numeric_limits<double>::infinity();
  cost.nearest_neighbor_ms = std::numeric_limits<double>::infinity();
  // Interleaved, so that a burst of load on the machine does not fall on one matcher only.
  for (int run = 0; run < kRuns; ++run) {
    {
      DescriptorLayerCache fresh;  // a query's first prediction runs its descriptor layers
      const Timer timer;
      network.Predict(probe, probe_images, map.label_tree(), masked ? &map.visibility() : nullptr,
                      &fresh);
      cost.network_ms = std::min(cost.network_ms, timer.ElapsedMilliseconds());
    }
    const Timer timer;
    const DescriptorMatrix unit_probe = UnitRows(probe);
    for (const uint32_t image : probe_images) {
      nearest_neighbor.Match(unit_probe, image, options.nearest_neighbor);
    }
    cost.nearest_neighbor_ms = std::min(cost.nearest_neighbor_ms, timer.ElapsedMilliseconds());
  }
  return cost;
}

Matcher ResolveMatcher(Matcher requested, const nlohmann::json& metadata, bool has_network,
                       bool has_observations) {
  if (requested != Matcher::kAuto) return requested;
  return AutoMatcher(MatchingCost::FromMetadata(metadata), has_network, has_observations);
}

std::string DescribeAutoMatcher(const std::optional<MatchingCost>& cost, bool has_network,
                                bool has_observations) {
  const Matcher matcher = AutoMatcher(cost, has_network, has_observations);
  std::string why;
  if (!has_network) {
    why = "the map has no trained network";
  } else if (!cost.has_value()) {
    why = "the map holds no timing of both matchers: `hscloc train` records one";
  } else {
    why = fmt::format(
        "matching {} keypoints against {} images took the network {:.1f} ms and nearest "
        "neighbour {:.1f} ms when the map was trained{}",
        cost->keypoints, cost->images, cost->network_ms, cost->nearest_neighbor_ms,
        has_observations ? "" : "; the map is loaded without its observations");
  }
  return fmt::format("matcher auto: {} ({})", MatcherName(matcher), why);
}

std::string DescribeMatcher(const Localizer& localizer, Matcher requested) {
  if (requested != Matcher::kAuto) return "matcher " + MatcherName(requested);
  return DescribeAutoMatcher(MatchingCost::FromMetadata(localizer.map().metadata()),
                             localizer.network() != nullptr,
                             localizer.map().scene().NumObservations() > 0);
}

}  // namespace hscloc
