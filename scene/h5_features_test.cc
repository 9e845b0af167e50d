#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <hdf5.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <random>

#include "scene/feature_io.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;

// The message of the std::invalid_argument that `f` throws; a failure when it throws none.
// Keypoints lie inside a 1536 x 1024 image, where shifting by 0.5 px and back is exact in float.
ImageFeatures RandomFeatures(int num_keypoints, int dimension, bool with_scores,
                             std::mt19937* random) {
  std::uniform_real_distribution<float> x(0.5f, 1535.5f), y(0.5f, 1023.5f), value(-1.f, 1.f),
      score(0.f, 1.f);
  ImageFeatures features;
  features.keypoints.resize(num_keypoints, 2);
  features.descriptors.resize(num_keypoints, dimension);
  for (int i = 0; i < num_keypoints; ++i) {
    features.keypoints.row(i) << x(*random), y(*random);
    for (int d = 0; d < dimension; ++d) features.descriptors(i, d) = value(*random);
  }
  if (with_scores) {
    features.scores.resize(num_keypoints);
    for (int i = 0; i < num_keypoints; ++i) features.scores(i) = score(*random);
  }
  return features;
}

MATCHER_P(MatrixEq, expected, "") {
  if (arg.rows() != expected.rows() || arg.cols() != expected.cols()) {
    *result_listener << "shape " << arg.rows() << " x " << arg.cols();
    return false;
  }
  return arg == expected;
}

// |a - b| within `relative` of |b|, plus half's subnormal spacing for values near zero.
MATCHER_P2(ElementsNear, expected, relative, "") {
  if (arg.rows() != expected.rows() || arg.cols() != expected.cols()) {
    *result_listener << "shape " << arg.rows() << " x " << arg.cols();
    return false;
  }
  for (Eigen::Index i = 0; i < expected.size(); ++i) {
    const float want = expected.data()[i], got = arg.data()[i];
    if (std::abs(got - want) > relative * std::abs(want) + 1e-7f) {
      *result_listener << "element " << i << ": " << got << " vs. " << want;
      return false;
    }
  }
  return true;
}

// Raw HDF5, independent of the code under test, for files hloc (h5py) would write.
class RawH5File {
 public:
  explicit RawH5File(const std::filesystem::path& path)
      : file_(H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT)) {
    EXPECT_GE(file_, 0);
  }
  ~RawH5File() {
    CloseGroups();
    H5Fclose(file_);
  }
  hid_t Group(const std::string& name) {
    const hid_t group = H5Gcreate2(file_, name.c_str(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    EXPECT_GE(group, 0) << name;
    groups_.push_back(group);
    return group;
  }
  void Dataset(hid_t group, const char* name, std::vector<hsize_t> shape,
               const std::vector<float>& values) {
    const hid_t space = H5Screate_simple(shape.size(), shape.data(), nullptr);
    const hid_t dataset =
        H5Dcreate2(group, name, H5T_IEEE_F32LE, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    EXPECT_GE(H5Dwrite(dataset, H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()), 0);
    H5Dclose(dataset);
    H5Sclose(space);
  }
  void CloseGroups() {
    for (const hid_t group : groups_) H5Gclose(group);
    groups_.clear();
  }

 private:
  hid_t file_;
  std::vector<hid_t> groups_;
};

// One float dataset of an HDF5 file, read with raw HDF5 calls: (shape, values).
std::pair<std::vector<hsize_t>, std::vector<float>> ReadRawDataset(
    const std::filesystem::path& path, const std::string& dataset_path) {
  const hid_t file = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const hid_t dataset = H5Dopen2(file, dataset_path.c_str(), H5P_DEFAULT);
  const hid_t space = H5Dget_space(dataset);
  std::vector<hsize_t> shape(H5Sget_simple_extent_ndims(space));
  H5Sget_simple_extent_dims(space, shape.data(), nullptr);
  std::vector<float> values(H5Sget_simple_extent_npoints(space));
  H5Dread(dataset, H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data());
  H5Sclose(space);
  H5Dclose(dataset);
  H5Fclose(file);
  return {shape, values};
}

TEST(H5Features, Float32RoundTripIsExactWithNestedNames) {
  testing::TempDir dir;
  std::mt19937 random(7);
  const std::map<std::string, ImageFeatures> written = {
      {"db/0001.jpg", RandomFeatures(300, 128, true, &random)},
      {"db/0002.jpg", RandomFeatures(0, 128, false, &random)},
      {"query/day/q 1.jpg", RandomFeatures(57, 128, false, &random)},
      {"top.jpg", RandomFeatures(1, 128, true, &random)},
  };
  H5FeatureWriter writer(dir / "features.h5", H5FloatPrecision::kFloat32);
  for (const auto& [name, features] : written) writer.Write(name, features, 1536, 1024);
  writer.Close();

  const auto reader = OpenH5Features(dir / "features.h5");
  EXPECT_THAT(reader->ImageNames(),
              ::testing::ElementsAre("db/0001.jpg", "db/0002.jpg", "query/day/q 1.jpg", "top.jpg"));
  EXPECT_FALSE(reader->HasImage("db"));
  for (const auto& [name, features] : written) {
    SCOPED_TRACE(name);
    const ImageFeatures read = reader->Read(name);
    EXPECT_THAT(read.keypoints, MatrixEq(features.keypoints));
    EXPECT_THAT(read.descriptors, MatrixEq(features.descriptors));
    EXPECT_THAT(read.scores, MatrixEq(features.scores));
    EXPECT_EQ(read.Dimension(), 128);
    EXPECT_EQ(reader->ImageSize(name), (PhotoSize{1536, 1024}));
  }
  // hloc's layout: one group per name component, descriptors D x N, image_size (w, h).
  EXPECT_EQ(ReadRawDataset(dir / "features.h5", "db/0001.jpg/descriptors").first,
            (std::vector<hsize_t>{128, 300}));
  EXPECT_EQ(ReadRawDataset(dir / "features.h5", "query/day/q 1.jpg/image_size").second,
            (std::vector<float>{1536, 1024}));
}

TEST(H5Features, Float16RoundTripIsWithinHalfPrecision) {
  testing::TempDir dir;
  std::mt19937 random(11);
  const ImageFeatures features = RandomFeatures(500, 256, true, &random);
  H5FeatureWriter writer(dir / "half.h5", H5FloatPrecision::kFloat16);
  writer.Write("a.jpg", features, 1536, 1024);
  writer.Close();

  const ImageFeatures read = OpenH5Features(dir / "half.h5")->Read("a.jpg");
  EXPECT_THAT(read.keypoints, MatrixEq(features.keypoints));  // kept float32
  EXPECT_THAT(read.descriptors, ElementsNear(features.descriptors, 1e-3f));
  EXPECT_THAT(read.scores, ElementsNear(features.scores, 1e-3f));
  EXPECT_NE(read.descriptors, features.descriptors) << "descriptors were not stored as float16";

  const hid_t file = H5Fopen((dir / "half.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const hid_t dataset = H5Dopen2(file, "a.jpg/descriptors", H5P_DEFAULT);
  const hid_t type = H5Dget_type(dataset);
  EXPECT_EQ(H5Tget_size(type), 2u);
  EXPECT_EQ(H5Tget_class(type), H5T_FLOAT);
  H5Tclose(type);
  H5Dclose(dataset);
  H5Fclose(file);
}

// Every finite float16 value, as float.
std::vector<float> AllFiniteHalves() {
  std::vector<float> values;
  for (int sign : {1, -1}) {
    for (int exponent = 0; exponent < 31; ++exponent) {
      for (int mantissa = 0; mantissa < 1024; ++mantissa) {
        values.push_back(sign * (exponent == 0 ? std::ldexp(mantissa, -24)
                                               : std::ldexp(1024 + mantissa, exponent - 25)));
      }
    }
  }
  return values;
}

TEST(H5Features, Float16StoresEveryHalfExactlyAndRoundsToNearest) {
  testing::TempDir dir;
  const std::vector<float> halves = AllFiniteHalves();
  // Each row: an exact half, then values that must round to a known half. 0.12498 rounds up
  // across a power of two, where a conversion with a carry bug halves it.
  const std::vector<std::pair<float, float>> rounding = {
      {0.12498f, 0.125f},
      {2047.9f, 2048.f},
      {65519.f, 65504.f},
      {1.f + std::ldexp(1.f, -11), 1.f},  // a tie goes to the even mantissa
      {1.f + 3 * std::ldexp(1.f, -11), 1.f + std::ldexp(1.f, -9)},
      {std::ldexp(1.f, -25) * 1.5f, std::ldexp(1.f, -24)},  // subnormal
      {-std::ldexp(1.f, -26), -0.f}};
  ImageFeatures features;
  features.keypoints = KeypointMatrix::Constant(halves.size(), 2, 1.f);
  features.descriptors.resize(halves.size(), 2);
  for (size_t i = 0; i < halves.size(); ++i) {
    features.descriptors(i, 0) = halves[i];
    features.descriptors(i, 1) = rounding[i % rounding.size()].first;
  }
  H5FeatureWriter writer(dir / "halves.h5", H5FloatPrecision::kFloat16);
  writer.Write("all", features, 1, 1);
  ImageFeatures too_large = features;
  too_large.descriptors(5, 1) = 65520.f;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { writer.Write("too_large", too_large, 1, 1); }),
              HasSubstr("65520"));
  writer.Close();

  const ImageFeatures read = OpenH5Features(dir / "halves.h5")->Read("all");
  for (size_t i = 0; i < halves.size(); ++i) {
    ASSERT_EQ(read.descriptors(i, 0), halves[i]) << i;
    ASSERT_EQ(read.descriptors(i, 1), rounding[i % rounding.size()].second)
        << rounding[i % rounding.size()].first;
  }
}

TEST(H5Features, KeypointsShiftByHalfAPixelBetweenHlocAndColmap) {
  testing::TempDir dir;
  {
    RawH5File raw(dir / "raw.h5");
    const hid_t group = raw.Group("img.jpg");
    raw.Dataset(group, "keypoints", {2, 2}, {0.f, 0.f, 10.25f, 3.5f});
    raw.Dataset(group, "descriptors", {3, 2}, {1, 2, 3, 4, 5, 6});
  }
  const ImageFeatures read = OpenH5Features(dir / "raw.h5")->Read("img.jpg");
  EXPECT_THAT(
      read.keypoints,
      MatrixEq(KeypointMatrix((KeypointMatrix(2, 2) << 0.5f, 0.5f, 10.75f, 4.f).finished())));
  EXPECT_THAT(read.descriptors,
              MatrixEq(DescriptorMatrix((DescriptorMatrix(2, 3) << 1, 3, 5, 2, 4, 6).finished())));
  EXPECT_EQ(read.scores.size(), 0);

  H5FeatureWriter writer(dir / "written.h5", H5FloatPrecision::kFloat32);
  writer.Write("img.jpg", read, 20, 10);
  writer.Close();
  EXPECT_EQ(ReadRawDataset(dir / "written.h5", "img.jpg/keypoints").second,
            (std::vector<float>{0.f, 0.f, 10.25f, 3.5f}));
  EXPECT_EQ(ReadRawDataset(dir / "written.h5", "img.jpg/descriptors").second,
            (std::vector<float>{1, 2, 3, 4, 5, 6}));
}

TEST(H5Features, GlobalDescriptorsRoundTrip) {
  testing::TempDir dir;
  std::mt19937 random(3);
  std::normal_distribution<float> normal;
  std::unordered_map<std::string, Eigen::VectorXf> descriptors;
  for (const char* name : {"db/a.jpg", "db/b.jpg", "query/c.jpg"}) {
    Eigen::VectorXf descriptor(4096);
    for (auto& value : descriptor) value = normal(random);
    descriptors[name] = descriptor.normalized();
  }
  WriteH5GlobalDescriptors(dir / "global32.h5", descriptors, H5FloatPrecision::kFloat32);
  const auto exact = ReadH5GlobalDescriptors(dir / "global32.h5");
  ASSERT_EQ(exact.size(), descriptors.size());
  for (const auto& [name, descriptor] : descriptors) {
    EXPECT_THAT(exact.at(name), MatrixEq(descriptor)) << name;
  }

  WriteH5GlobalDescriptors(dir / "global16.h5", descriptors, H5FloatPrecision::kFloat16);
  const auto half = ReadH5GlobalDescriptors(dir / "global16.h5");
  ASSERT_EQ(half.size(), descriptors.size());
  for (const auto& [name, descriptor] : descriptors) {
    EXPECT_THAT(half.at(name), ElementsNear(descriptor, 1e-3f)) << name;
  }
}

TEST(H5Features, GlobalDescriptorsOfDifferentDimensionsAreRejected) {
  testing::TempDir dir;
  const std::unordered_map<std::string, Eigen::VectorXf> descriptors = {
      {"a.jpg", Eigen::VectorXf::Ones(8)}, {"b.jpg", Eigen::VectorXf::Ones(9)}};
  const std::string message = testing::InvalidArgumentMessage([&] {
    WriteH5GlobalDescriptors(dir / "global.h5", descriptors, H5FloatPrecision::kFloat32);
  });
  EXPECT_THAT(message, HasSubstr("b.jpg"));
  EXPECT_THAT(message, HasSubstr("a.jpg"));
}

TEST(H5Features, WriterRejectsDuplicatesAndInconsistentFeatures) {
  testing::TempDir dir;
  std::mt19937 random(5);
  H5FeatureWriter writer(dir / "f.h5", H5FloatPrecision::kFloat32);
  const ImageFeatures features = RandomFeatures(10, 32, true, &random);
  writer.Write("a.jpg", features, 640, 480);
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { writer.Write("a.jpg", features, 640, 480); }),
              HasSubstr("written before"));

  ImageFeatures short_scores = features;
  short_scores.scores.conservativeResize(9);
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { writer.Write("b.jpg", short_scores, 640, 480); }),
      HasSubstr("9 scores for 10 keypoints"));
  ImageFeatures nan_descriptor = features;
  nan_descriptor.descriptors(3, 4) = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { writer.Write("c.jpg", nan_descriptor, 640, 480); }),
      HasSubstr("descriptor value nan is not finite"));
  EXPECT_THAT(
      testing::InvalidArgumentMessage([&] { writer.Write("d//e.jpg", features, 640, 480); }),
      HasSubstr("d//e.jpg"));
}

TEST(H5Features, AppendingKeepsTheImagesWrittenBefore) {
  testing::TempDir dir;
  std::mt19937 random(3);
  const ImageFeatures first = RandomFeatures(20, 16, true, &random);
  const ImageFeatures second = RandomFeatures(30, 16, true, &random);
  {
    H5FeatureWriter writer(dir / "f.h5", H5FloatPrecision::kFloat32, H5WriteMode::kAppend);
    EXPECT_FALSE(writer.HasImage("db/a.jpg"));
    writer.Write("db/a.jpg", first, 640, 480);
    writer.Close();
  }
  H5FeatureWriter writer(dir / "f.h5", H5FloatPrecision::kFloat32, H5WriteMode::kAppend);
  EXPECT_TRUE(writer.HasImage("db/a.jpg"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { writer.Write("db/a.jpg", first, 640, 480); }),
              HasSubstr("written before"));
  writer.Write("db/b.jpg", second, 640, 480);
  writer.Close();
  const auto reader = OpenH5Features(dir / "f.h5");
  EXPECT_THAT(reader->ImageNames(), ::testing::ElementsAre("db/a.jpg", "db/b.jpg"));
  EXPECT_THAT(reader->Read("db/a.jpg").descriptors, MatrixEq(first.descriptors));
  EXPECT_THAT(reader->Read("db/b.jpg").keypoints, MatrixEq(second.keypoints));

  std::ofstream(dir / "not.h5") << "not HDF5";
  EXPECT_THAT(testing::InvalidArgumentMessage([&] {
                H5FeatureWriter(dir / "not.h5", H5FloatPrecision::kFloat32, H5WriteMode::kAppend);
              }),
              HasSubstr((dir / "not.h5").string()));
}

TEST(H5Features, NanDescriptorIsReportedWithFileAndImage) {
  testing::TempDir dir;
  {
    RawH5File raw(dir / "nan.h5");
    const hid_t group = raw.Group("img.jpg");
    raw.Dataset(group, "keypoints", {2, 2}, {1, 1, 2, 2});
    raw.Dataset(group, "descriptors", {2, 2}, {0.f, 1.f, std::nanf(""), 0.f});
  }
  const auto reader = OpenH5Features(dir / "nan.h5");
  const std::string message = testing::InvalidArgumentMessage([&] { reader->Read("img.jpg"); });
  EXPECT_THAT(message, HasSubstr((dir / "nan.h5").string()));
  EXPECT_THAT(message, HasSubstr("img.jpg"));
  EXPECT_THAT(message, HasSubstr("descriptor of keypoint 0 is not finite (dimension 1)"));
}

TEST(H5Features, MalformedShapesAreReported) {
  testing::TempDir dir;
  {
    RawH5File raw(dir / "bad.h5");
    const hid_t three_columns = raw.Group("three_columns.jpg");
    raw.Dataset(three_columns, "keypoints", {2, 3}, {1, 1, 1, 2, 2, 2});
    raw.Dataset(three_columns, "descriptors", {1, 2}, {0, 0});
    const hid_t too_few = raw.Group("too_few_descriptors.jpg");
    raw.Dataset(too_few, "keypoints", {2, 2}, {1, 1, 2, 2});
    raw.Dataset(too_few, "descriptors", {4, 1}, {0, 0, 0, 0});
    const hid_t no_descriptors = raw.Group("no_descriptors.jpg");
    raw.Dataset(no_descriptors, "keypoints", {1, 2}, {1, 1});
    // hloc's files before image_size, and sizes that are not (width, height) in whole pixels.
    const hid_t no_size = raw.Group("no_size.jpg");
    raw.Dataset(no_size, "keypoints", {1, 2}, {1, 1});
    raw.Dataset(no_size, "descriptors", {1, 1}, {1});
    const hid_t three_numbers = raw.Group("three_numbers.jpg");
    raw.Dataset(three_numbers, "keypoints", {1, 2}, {1, 1});
    raw.Dataset(three_numbers, "image_size", {3}, {640, 480, 3});
    const hid_t fractional = raw.Group("fractional.jpg");
    raw.Dataset(fractional, "keypoints", {1, 2}, {1, 1});
    raw.Dataset(fractional, "image_size", {2}, {640.5f, 480});
  }
  const auto reader = OpenH5Features(dir / "bad.h5");
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->Read("three_columns.jpg"); }),
              HasSubstr("'three_columns.jpg', dataset keypoints: shape 2 x 3, expected N x 2"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->Read("too_few_descriptors.jpg"); }),
              HasSubstr("shape 4 x 1, expected D x 2"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->Read("no_descriptors.jpg"); }),
              HasSubstr("dataset descriptors: missing"));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->Read("absent.jpg"); }),
              HasSubstr("no image 'absent.jpg'"));
  EXPECT_EQ(reader->ImageSize("no_size.jpg"), std::nullopt);
  for (const char* name : {"three_numbers.jpg", "fractional.jpg"}) {
    EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->ImageSize(name); }),
                ::testing::AllOf(HasSubstr(name), HasSubstr("dataset image_size"),
                                 HasSubstr("expected 2 whole positive numbers")));
  }
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { reader->ImageSize("absent.jpg"); }),
              HasSubstr("no image 'absent.jpg'"));
}

TEST(H5Features, TruncatedFileIsAnErrorNotACrash) {
  testing::TempDir dir;
  std::mt19937 random(13);
  {
    H5FeatureWriter writer(dir / "full.h5", H5FloatPrecision::kFloat32);
    for (int i = 0; i < 8; ++i) {
      writer.Write("db/" + std::to_string(i) + ".jpg", RandomFeatures(512, 128, true, &random),
                   1536, 1024);
    }
  }
  std::ifstream full(dir / "full.h5", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(full)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 1000000u);
  std::ofstream(dir / "half.h5", std::ios::binary).write(bytes.data(), bytes.size() / 2);

  const std::string message = testing::InvalidArgumentMessage([&] {
    const auto reader = OpenH5Features(dir / "half.h5");
    for (const std::string& name : reader->ImageNames()) reader->Read(name);
  });
  EXPECT_THAT(message, HasSubstr((dir / "half.h5").string()));
}

TEST(H5Features, MissingAndNonHdf5FilesAreReported) {
  testing::TempDir dir;
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { OpenH5Features(dir / "absent.h5"); }),
              HasSubstr("does not exist"));
  std::ofstream(dir / "text.h5") << "not an HDF5 file\n";
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { OpenH5Features(dir / "text.h5"); }),
              HasSubstr((dir / "text.h5").string()));
  EXPECT_THAT(testing::InvalidArgumentMessage([&] { ReadH5GlobalDescriptors(dir / "text.h5"); }),
              HasSubstr((dir / "text.h5").string()));
}

}  // namespace
}  // namespace hscloc
