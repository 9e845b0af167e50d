#include "features/image_extraction.h"

#include <algorithm>
#include <atomic>
#include <cctype>
#include <fstream>
#include <mutex>
#include <set>

#include "util/check.h"
#include "util/parallel.h"
#include "util/progress_bar.h"
#include "util/timer.h"

namespace hscloc {
namespace {

bool IsImageFile(const std::filesystem::path& path) {
  static const std::set<std::string> kExtensions = {".jpg", ".jpeg", ".png",
                                                    ".bmp", ".tif",  ".tiff"};
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  return kExtensions.count(extension) > 0;
}

// Extractors handed to worker chunks one at a time: an OpenCV DNN network serves one thread, and
// loading one per chunk would repeat the model load many times.
class ExtractorPool {
 public:
  explicit ExtractorPool(const FeatureExtractorOptions& options) : options_(options) {}

  std::unique_ptr<FeatureExtractor> Acquire() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!idle_.empty()) {
        std::unique_ptr<FeatureExtractor> extractor = std::move(idle_.back());
        idle_.pop_back();
        return extractor;
      }
    }
    return CreateFeatureExtractor(options_);
  }

  void Release(std::unique_ptr<FeatureExtractor> extractor) {
    std::lock_guard<std::mutex> lock(mutex_);
    idle_.push_back(std::move(extractor));
  }

 private:
  const FeatureExtractorOptions options_;
  std::mutex mutex_;
  std::vector<std::unique_ptr<FeatureExtractor>> idle_;
};

}  // namespace

std::vector<std::string> ListImages(const std::filesystem::path& image_dir) {
  if (!std::filesystem::is_directory(image_dir)) {
    ThrowInvalidArgument("image folder {} does not exist or is not a folder", image_dir.string());
  }
  std::vector<std::string> names;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(image_dir)) {
    if (entry.is_regular_file() && IsImageFile(entry.path())) {
      names.push_back(entry.path().lexically_relative(image_dir).generic_string());
    }
  }
  if (names.empty()) ThrowInvalidArgument("image folder {} holds no photo", image_dir.string());
  std::sort(names.begin(), names.end());
  return names;
}

std::vector<std::string> ReadImageList(const std::filesystem::path& list_path) {
  std::ifstream file(list_path);
  if (!file) ThrowInvalidArgument("cannot read the image list {}", list_path.string());
  std::vector<std::string> names;
  std::string line;
  while (std::getline(file, line)) {
    line.erase(line.find_last_not_of(" \t\r") + 1);
    line.erase(0, line.find_first_not_of(" \t"));
    if (!line.empty()) names.push_back(line);
  }
  if (names.empty()) ThrowInvalidArgument("the image list {} names no image", list_path.string());
  return names;
}

void ImageExtractionOptions::Check() const { extractor.Check(); }

ImageExtractionSummary ExtractImagesToH5(const std::filesystem::path& image_dir,
                                         const std::vector<std::string>& image_names,
                                         const std::filesystem::path& out_path,
                                         const ImageExtractionOptions& options) {
  options.Check();
  const Timer timer;
  ExtractorPool pool(options.extractor);
  // A missing or bad model fails here, before the output file is touched.
  pool.Release(pool.Acquire());
  if (out_path.has_parent_path()) std::filesystem::create_directories(out_path.parent_path());
  H5FeatureWriter writer(out_path, options.precision, H5WriteMode::kAppend);
  ImageExtractionSummary summary;
  summary.num_images = static_cast<int64_t>(image_names.size());
  std::vector<std::string> pending;
  for (const std::string& name : image_names) {
    if (!writer.HasImage(name)) pending.push_back(name);
  }
  summary.num_skipped = summary.num_images - static_cast<int64_t>(pending.size());

  ProgressBar progress(
      "extract " + FeatureTypeName(options.extractor.type), pending.size(),
      options.show_progress ? ProgressBar::Display::kAuto : ProgressBar::Display::kNever);
  std::mutex writer_mutex;  // HDF5 writes one at a time
  std::atomic<int64_t> num_keypoints{0};
  ParallelFor(pending.size(), options.num_threads, [&](size_t begin, size_t end) {
    std::unique_ptr<FeatureExtractor> extractor = pool.Acquire();
    for (size_t i = begin; i < end; ++i) {
      const ExtractedFeatures extracted = extractor->Extract(image_dir / pending[i]);
      {
        std::lock_guard<std::mutex> lock(writer_mutex);
        writer.Write(pending[i], extracted.features, extracted.width, extracted.height);
      }
      num_keypoints += extracted.features.NumKeypoints();
      progress.Advance();
    }
    pool.Release(std::move(extractor));
  });
  progress.Finish();
  writer.Close();
  summary.num_extracted = static_cast<int64_t>(pending.size());
  summary.num_keypoints = num_keypoints;
  summary.seconds = timer.ElapsedSeconds();
  return summary;
}

}  // namespace hscloc
