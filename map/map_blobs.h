// Every blob name and metadata key of a map bundle (map/map_bundle.h), in one place: the map
// builder and the trainer write them, the loaded map, the tools and the benchmarks read them.
#pragma once

namespace hscloc {

namespace map_blobs {
inline constexpr char kManifest[] = "manifest.json";  // written by MapBundleWriter itself
inline constexpr char kScene[] = "scene.bin";         // cameras, images, points
// Training data, and what nearest-neighbour matching searches (loaded to serve only for it).
inline constexpr char kObservations[] = "observations.bin";
inline constexpr char kLabelTree[] = "label_tree.bin";
inline constexpr char kVisibility[] = "visibility.bin";
// Each point's unit mean descriptor at 8 bits (map/point_descriptors.h); absent from older maps.
inline constexpr char kPointDescriptors[] = "point_descriptors.bin";
inline constexpr char kVlad[] = "vlad.bin";  // absent when the global descriptors are external
inline constexpr char kGlobalDescriptors[] = "global_descriptors.bin";
inline constexpr char kGlobalIndex[] = "global_index.bin";
inline constexpr char kNetwork[] = "network.pt";  // absent until `hscloc train`
inline constexpr char kTrainingLog[] = "training_log.csv";
}  // namespace map_blobs

// Keys of the manifest's "metadata" object.
namespace map_metadata {
inline constexpr char kDescriptorDim[] = "descriptor_dim";
inline constexpr char kNumImages[] = "num_images";
inline constexpr char kNumPoints[] = "num_points";
inline constexpr char kNumObservations[] = "num_observations";
inline constexpr char kNumCameras[] = "num_cameras";
inline constexpr char kLabelTree[] = "label_tree";
inline constexpr char kRetrieval[] = "retrieval";
inline constexpr char kSources[] = "sources";
// The trained network's summary: shape, options, training (below) and evaluations.
inline constexpr char kNetwork[] = "network";
inline constexpr char kTraining[] = "training";
inline constexpr char kHoldoutFraction[] = "holdout_fraction";
inline constexpr char kHoldoutSeed[] = "holdout_seed";
}  // namespace map_metadata

}  // namespace hscloc
