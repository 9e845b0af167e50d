// Making a descriptor bank from real photo sets: each set's photos are described by a local
// feature, its map triangulated for that feature from the set's own poses (hscloc triangulate),
// and the photos described again under a night-like transform; a track's view keeps the night
// descriptor of the night keypoint found where its day keypoint was.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <opencv2/core/mat.hpp>
#include <string>
#include <vector>

#include "features/feature_extractor.h"
#include "scene/descriptor_bank.h"
#include "scene/feature_io.h"
#include "scene/reconstruction.h"
#include "triangulation/map_triangulation.h"

namespace hscloc {

// A street photo as a phone takes it at night: under-exposed, then brightened by a gamma curve
// (the shadows lifted, the contrast of the lit parts kept), warm sodium-lamp colour, sensor noise
// that the brightening amplifies, a little motion or focus blur, and a stronger JPEG. Each
// parameter is drawn per photo from its range.
struct NightTransformOptions {
  double exposure_min = 0.15;  // scale of linear intensity
  double exposure_max = 0.35;
  double gamma_min = 1.8;  // output = input^(1 / gamma), on the under-exposed image
  double gamma_max = 2.4;
  double blue_gain = 0.65;  // per channel, red kept at 1
  double green_gain = 0.85;
  double noise_sigma = 0.02;  // Gaussian sensor noise before the gamma, in [0, 1] intensity
  double blur_sigma_max_px = 1.2;
  int jpeg_quality = 55;
  void Check() const;
};

// The night version of a BGR 8-bit photo; the same photo, options and key give the same image.
cv::Mat NightPhoto(const cv::Mat& bgr, const NightTransformOptions& options, uint64_t key);

// Tracks from a reconstruction and the features its 2D points index: each 3D point with at least
// `min_track_length` views becomes a track of its views' unit descriptors and local view
// directions (LocalViewDirection from the point towards each camera, against the track's mean
// direction and the set's up, the mean of its cameras' up vectors). With `night`, each view keeps
// the descriptor of the night photo's keypoint nearest its keypoint, when one lies within
// `night_match_px` pixels.
DescriptorBank BankFromReconstruction(const Reconstruction& reconstruction,
                                      const FeatureReader& day, const FeatureReader* night,
                                      double night_match_px, int min_track_length,
                                      const std::string& feature, const std::string& source);

struct BankSetOptions {
  FeatureExtractorOptions extractor;
  MapTriangulationOptions triangulation;
  NightTransformOptions night;
  double night_match_px = 2.0;
  int min_track_length = 2;
  bool show_progress = true;
  void Check() const;
};

// The bank of one real set (a folder with images/ and map/, the layout of the project's test
// data): day features, the triangulated map and the night photos' features are written under
// `work_dir` (reused when there: an interrupted run resumes). Throws std::invalid_argument naming
// the set when its folders are missing.
DescriptorBank BankFromSet(const std::filesystem::path& set_dir,
                           const std::filesystem::path& work_dir, const BankSetOptions& options);

// The name a set's tracks are recorded under in a bank: its folder's name, however the path is
// written ("data/lund", "data/lund/" and "./data/lund" are all "lund").
std::string BankSetName(const std::filesystem::path& set_dir);

// Called after each set of BankFromSets with the set, its bank and the seconds it took.
using BankSetDone =
    std::function<void(const std::filesystem::path&, const DescriptorBank&, double seconds)>;

// The banks of several sets concatenated, each set's work under `work_dir`/<number>-<name> (two
// sets may share a folder name; an interrupted run resumes there). Throws std::invalid_argument
// when the sets hold no track of two or more views.
DescriptorBank BankFromSets(const std::vector<std::filesystem::path>& set_dirs,
                            const std::filesystem::path& work_dir, const BankSetOptions& options,
                            const BankSetDone& done = nullptr);

}  // namespace hscloc
