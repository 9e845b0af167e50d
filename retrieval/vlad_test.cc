#include "retrieval/vlad.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <fstream>
#include <numeric>
#include <sstream>

#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

constexpr int kDim = 32;

Eigen::VectorXf RandomUnitVector(Random& random, int dim) {
  Eigen::VectorXf v(dim);
  for (int d = 0; d < dim; ++d) v[d] = static_cast<float>(random.Normal());
  return v.normalized();
}

// Views of a few places: every place has its own landmarks, each view sees most of them with
// descriptor noise, plus clutter. Two views of a place share landmarks; views of different places
// share none, so retrieval has a clear right answer.
struct PlaceViews {
  std::vector<DescriptorMatrix> views;  // views_per_place consecutive views per place
  int views_per_place = 0;
};

PlaceViews MakePlaceViews(int num_places, int views_per_place, uint64_t seed,
                          float descriptor_scale = 1.0f) {
  constexpr int kLandmarksPerPlace = 60;
  constexpr int kClutterPerView = 20;
  constexpr float kNoise = 0.3f;
  PlaceViews result;
  result.views_per_place = views_per_place;
  for (int p = 0; p < num_places; ++p) {
    Random place_random(seed, {0, static_cast<uint64_t>(p)});
    std::vector<Eigen::VectorXf> landmarks;
    for (int l = 0; l < kLandmarksPerPlace; ++l) {
      landmarks.push_back(RandomUnitVector(place_random, kDim));
    }
    for (int v = 0; v < views_per_place; ++v) {
      Random random(seed, {1, static_cast<uint64_t>(p), static_cast<uint64_t>(v)});
      std::vector<Eigen::VectorXf> rows;
      for (const Eigen::VectorXf& landmark : landmarks) {
        if (!random.Bernoulli(0.8)) continue;
        rows.push_back((landmark + kNoise * RandomUnitVector(random, kDim)).normalized());
      }
      for (int c = 0; c < kClutterPerView; ++c) rows.push_back(RandomUnitVector(random, kDim));
      DescriptorMatrix descriptors(rows.size(), kDim);
      for (size_t r = 0; r < rows.size(); ++r) {
        descriptors.row(r) = descriptor_scale * rows[r].transpose();
      }
      result.views.push_back(std::move(descriptors));
    }
  }
  return result;
}

VladOptions SmallOptions() {
  VladOptions options;
  options.num_words = 8;
  options.whitened_dim = 32;
  options.kmeans_iterations = 10;
  options.seed = 7;
  return options;
}

std::string Serialize(const VladEncoder& encoder) {
  std::ostringstream stream;
  encoder.Write(stream);
  return stream.str();
}

TEST(VladOptionsTest, CheckNamesTheField) {
  const auto expect_message = [](VladOptions options, const std::string& field) {
    try {
      options.Check();
      ADD_FAILURE() << "no exception for " << field;
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), HasSubstr(field));
    }
  };
  VladOptions options;
  EXPECT_NO_THROW(options.Check());
  options.num_words = 0;
  expect_message(options, "num_words");
  options = {};
  options.kmeans_iterations = 0;
  expect_message(options, "kmeans_iterations");
  options = {};
  options.max_training_descriptors = options.num_words - 1;
  expect_message(options, "max_training_descriptors");
  options = {};
  options.whitened_dim = -1;
  expect_message(options, "whitened_dim");
  options = {};
  options.whitening_regularization = -0.5;
  expect_message(options, "whitening_regularization");
}

TEST(VladEncoderTest, OutputIsUnitLengthWithAndWithoutWhitening) {
  const PlaceViews data = MakePlaceViews(12, 3, 1);
  for (const int whitened_dim : {0, 16}) {
    VladOptions options = SmallOptions();
    options.whitened_dim = whitened_dim;
    const VladEncoder encoder = VladEncoder::Train(data.views, options);
    EXPECT_EQ(encoder.descriptor_dim(), kDim);
    EXPECT_EQ(encoder.num_words(), options.num_words);
    EXPECT_EQ(encoder.output_dim(), whitened_dim > 0 ? whitened_dim : options.num_words * kDim);
    for (const DescriptorMatrix& view : data.views) {
      const Eigen::VectorXf code = encoder.Encode(view);
      ASSERT_EQ(code.size(), encoder.output_dim());
      EXPECT_NEAR(code.norm(), 1.0f, 1e-5f);
    }
  }
}

// The whitening's rows are split across threads in blocks: an encoding must not depend on how
// many, to the bit, or a query would retrieve differently on a busier server.
TEST(VladEncoderTest, EncodingIsTheSameOnAnyNumberOfThreads) {
  const PlaceViews data = MakePlaceViews(50, 3, 6);
  VladOptions options = SmallOptions();
  options.whitened_dim = 140;  // several blocks of rows
  const VladEncoder encoder = VladEncoder::Train(data.views, options);
  ASSERT_EQ(encoder.output_dim(), 140);
  for (size_t i = 0; i < data.views.size(); i += 15) {
    const Eigen::VectorXf one = encoder.Encode(data.views[i], 1);
    EXPECT_EQ(one, encoder.Encode(data.views[i], 3)) << "view " << i;
    EXPECT_EQ(one, encoder.Encode(data.views[i], 0)) << "view " << i;
  }
}

TEST(VladEncoderTest, InputScaleDoesNotMatter) {
  // SIFT arrives as 0..255 floats, SuperPoint as unit vectors: both are L2-normalized first.
  const PlaceViews unit = MakePlaceViews(8, 2, 2);
  const PlaceViews scaled = MakePlaceViews(8, 2, 2, 255.0f);
  const VladEncoder encoder = VladEncoder::Train(unit.views, SmallOptions());
  for (size_t i = 0; i < unit.views.size(); ++i) {
    EXPECT_TRUE(encoder.Encode(unit.views[i]).isApprox(encoder.Encode(scaled.views[i]), 1e-5f));
  }
}

TEST(VladEncoderTest, InvariantToTheOrderOfLocalDescriptors) {
  const PlaceViews data = MakePlaceViews(10, 2, 3);
  const VladEncoder encoder = VladEncoder::Train(data.views, SmallOptions());
  Random random(3, {99});
  for (const DescriptorMatrix& view : data.views) {
    DescriptorMatrix shuffled = view;
    for (Eigen::Index i = shuffled.rows(); i > 1; --i) {
      shuffled.row(i - 1).swap(shuffled.row(static_cast<Eigen::Index>(random.UniformInt(i))));
    }
    const Eigen::VectorXf original = encoder.Encode(view);
    const Eigen::VectorXf permuted = encoder.Encode(shuffled);
    EXPECT_LT((original - permuted).norm(), 1e-5f);
  }
}

TEST(VladEncoderTest, ImageIsClosestToItselfThenToItsPlace) {
  const PlaceViews data = MakePlaceViews(15, 2, 4);
  const VladEncoder encoder = VladEncoder::Train(data.views, SmallOptions());
  std::vector<Eigen::VectorXf> codes;
  for (const DescriptorMatrix& view : data.views) codes.push_back(encoder.Encode(view));
  for (size_t i = 0; i < codes.size(); ++i) {
    size_t best = 0;
    size_t best_other = codes.size();
    for (size_t j = 0; j < codes.size(); ++j) {
      if (codes[i].dot(codes[j]) > codes[i].dot(codes[best])) best = j;
      if (j != i && (best_other == codes.size() ||
                     codes[i].dot(codes[j]) > codes[i].dot(codes[best_other]))) {
        best_other = j;
      }
    }
    EXPECT_EQ(best, i);
    EXPECT_EQ(best_other / data.views_per_place, i / data.views_per_place) << "view " << i;
  }
}

TEST(VladEncoderTest, TrainingIsDeterministicForASeed) {
  const PlaceViews data = MakePlaceViews(10, 2, 5);
  VladOptions options = SmallOptions();
  // A sample smaller than the data exercises the codebook sampling too.
  options.max_training_descriptors = 500;
  const std::string first = Serialize(VladEncoder::Train(data.views, options));
  EXPECT_EQ(Serialize(VladEncoder::Train(data.views, options)), first);
  options.seed += 1;
  EXPECT_NE(Serialize(VladEncoder::Train(data.views, options)), first);
}

TEST(VladEncoderTest, WriteReadRoundTripGivesIdenticalEncodings) {
  const PlaceViews data = MakePlaceViews(10, 2, 6);
  for (const int whitened_dim : {0, 12}) {
    VladOptions options = SmallOptions();
    options.whitened_dim = whitened_dim;
    options.power_normalization = whitened_dim == 0;
    const VladEncoder encoder = VladEncoder::Train(data.views, options);
    const std::string bytes = Serialize(encoder);
    std::istringstream stream(bytes);
    const VladEncoder read = VladEncoder::Read(stream, "vlad.bin");
    EXPECT_EQ(read.output_dim(), encoder.output_dim());
    EXPECT_EQ(read.options().power_normalization, options.power_normalization);
    EXPECT_EQ(Serialize(read), bytes);
    for (const DescriptorMatrix& view : data.views) {
      EXPECT_EQ(read.Encode(view), encoder.Encode(view));
    }
  }
}

TEST(VladEncoderTest, WriteReadThroughAFile) {
  const PlaceViews data = MakePlaceViews(6, 2, 7);
  const VladEncoder encoder = VladEncoder::Train(data.views, SmallOptions());
  testing::TempDir dir;
  {
    std::ofstream file(dir / "vlad.bin", std::ios::binary);
    encoder.Write(file);
  }
  std::ifstream file(dir / "vlad.bin", std::ios::binary);
  const VladEncoder read = VladEncoder::Read(file, "vlad.bin");
  EXPECT_EQ(read.Encode(data.views[0]), encoder.Encode(data.views[0]));
}

TEST(VladEncoderTest, ReadRejectsCorruptDataAndNamesTheSource) {
  const PlaceViews data = MakePlaceViews(6, 2, 8);
  const std::string bytes = Serialize(VladEncoder::Train(data.views, SmallOptions()));
  const auto expect_error = [](const std::string& corrupt, const std::string& expected) {
    std::istringstream stream(corrupt);
    try {
      VladEncoder::Read(stream, "map/vlad.bin");
      ADD_FAILURE() << "no exception, expected " << expected;
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), HasSubstr("map/vlad.bin"));
      EXPECT_THAT(error.what(), HasSubstr(expected));
    }
  };
  expect_error("", "truncated");
  std::string bad_magic = bytes;
  bad_magic[0] = 'X';
  expect_error(bad_magic, "magic");
  std::string bad_version = bytes;
  bad_version[8] = 9;
  expect_error(bad_version, "version");
  for (const size_t length : {size_t{12}, size_t{40}, bytes.size() / 2, bytes.size() - 1}) {
    expect_error(bytes.substr(0, length), "truncated");
  }
}

TEST(VladEncoderTest, DimensionMismatchThrowsNamingBothDimensions) {
  const PlaceViews data = MakePlaceViews(6, 2, 9);
  const VladEncoder encoder = VladEncoder::Train(data.views, SmallOptions());
  const DescriptorMatrix wrong = DescriptorMatrix::Ones(5, 48);
  try {
    encoder.Encode(wrong);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("48"));
    EXPECT_THAT(error.what(), HasSubstr("32"));
  }
}

TEST(VladEncoderTest, NonFiniteDescriptorThrows) {
  const PlaceViews data = MakePlaceViews(6, 2, 10);
  const VladEncoder encoder = VladEncoder::Train(data.views, SmallOptions());
  DescriptorMatrix bad = data.views[0];
  bad(3, 5) = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(encoder.Encode(bad), std::invalid_argument);
}

TEST(VladEncoderTest, EmptyImageGivesZeros) {
  PlaceViews data = MakePlaceViews(6, 2, 11);
  // An empty image among the training images takes no part in the whitening.
  data.views.push_back(DescriptorMatrix(0, kDim));
  for (const int whitened_dim : {0, 8}) {
    VladOptions options = SmallOptions();
    options.whitened_dim = whitened_dim;
    const VladEncoder encoder = VladEncoder::Train(data.views, options);
    for (const DescriptorMatrix& empty : {DescriptorMatrix(0, kDim), DescriptorMatrix()}) {
      const Eigen::VectorXf code = encoder.Encode(empty);
      ASSERT_EQ(code.size(), encoder.output_dim());
      EXPECT_TRUE(code.isZero());
    }
  }
}

TEST(VladEncoderTest, WhitenedDimensionIsCappedAtImagesMinusOne) {
  const PlaceViews data = MakePlaceViews(5, 2, 12);
  VladOptions options = SmallOptions();
  options.whitened_dim = 256;
  const VladEncoder encoder = VladEncoder::Train(data.views, options);
  EXPECT_EQ(encoder.output_dim(), 9);
  for (const DescriptorMatrix& view : data.views) {
    EXPECT_NEAR(encoder.Encode(view).norm(), 1.0f, 1e-5f);
  }
}

TEST(VladEncoderTest, WhiteningFromTheCovarianceWhenImagesOutnumberDimensions) {
  // 4 words x 32 = 128 VLAD dimensions, 150 images: the direct (not Gram) eigen-decomposition.
  const PlaceViews data = MakePlaceViews(75, 2, 13);
  VladOptions options = SmallOptions();
  options.num_words = 4;
  options.whitened_dim = 64;
  const VladEncoder encoder = VladEncoder::Train(data.views, options);
  EXPECT_EQ(encoder.output_dim(), 64);
  size_t correct = 0;
  for (size_t i = 0; i < data.views.size(); i += 2) {
    const Eigen::VectorXf code = encoder.Encode(data.views[i]);
    EXPECT_NEAR(code.norm(), 1.0f, 1e-5f);
    const float same_place = code.dot(encoder.Encode(data.views[i + 1]));
    const float other_place = code.dot(encoder.Encode(data.views[(i + 2) % data.views.size()]));
    correct += same_place > other_place;
  }
  EXPECT_GE(correct, data.views.size() / 2 - 2);
}

TEST(VladEncoderTest, WhiteningFromImagesReadOneAtATime) {
  // 40 places, 2 views each: the codebook from the first 10 views, the whitening from all 80,
  // read in index order, once each.
  const PlaceViews data = MakePlaceViews(40, 2, 15);
  const VladOptions options = SmallOptions();
  const std::vector<DescriptorMatrix> codebook_views(data.views.begin(), data.views.begin() + 10);
  std::vector<size_t> reads;
  const VladEncoder::ImageReader read = [&](size_t image) {
    reads.push_back(image);
    return data.views[image];
  };
  const VladEncoder streamed = VladEncoder::Train(codebook_views, data.views.size(), read, options);
  std::vector<size_t> in_order(data.views.size());
  std::iota(in_order.begin(), in_order.end(), size_t{0});
  EXPECT_EQ(reads, in_order);
  // More whitening images than codebook images allow more dimensions than the codebook's images.
  EXPECT_EQ(streamed.output_dim(), options.whitened_dim);
  EXPECT_EQ(VladEncoder::Train(codebook_views, options).output_dim(), 9);

  // With the codebook's own images it is Train's encoder, byte for byte.
  std::ostringstream from_vector;
  VladEncoder::Train(codebook_views, options).Write(from_vector);
  std::ostringstream from_reader;
  VladEncoder::Train(
      codebook_views, codebook_views.size(), [&](size_t image) { return codebook_views[image]; },
      options)
      .Write(from_reader);
  EXPECT_EQ(from_vector.str(), from_reader.str());

  // A whitening image of another dimension is named.
  try {
    VladEncoder::Train(
        codebook_views, 3,
        [&](size_t image) {
          return image == 2 ? DescriptorMatrix::Ones(10, kDim + 1) : data.views[image];
        },
        options);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("dimension 33"));
  }
}

TEST(VladEncoderTest, TrainRejectsBadInput) {
  const PlaceViews data = MakePlaceViews(4, 2, 14);
  EXPECT_THROW(VladEncoder::Train({}, SmallOptions()), std::invalid_argument);
  std::vector<DescriptorMatrix> mixed = data.views;
  mixed.push_back(DescriptorMatrix::Ones(10, kDim + 1));
  try {
    VladEncoder::Train(mixed, SmallOptions());
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("dimension 33"));
  }
  VladOptions too_many_words = SmallOptions();
  too_many_words.num_words = 10000;
  too_many_words.max_training_descriptors = 10000;
  EXPECT_THROW(VladEncoder::Train(data.views, too_many_words), std::invalid_argument);
  VladOptions whitening = SmallOptions();
  EXPECT_THROW(VladEncoder::Train({data.views[0]}, whitening), std::invalid_argument);
  whitening.whitened_dim = 0;
  EXPECT_NO_THROW(VladEncoder::Train({data.views[0]}, whitening));
  VladOptions bad_options = SmallOptions();
  bad_options.num_words = -1;
  EXPECT_THROW(VladEncoder::Train(data.views, bad_options), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
