#include "retrieval/global_index.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <numeric>
#include <sstream>
#include <thread>

#include "util/random.h"

namespace hscloc {
namespace {

using ::testing::HasSubstr;
using RowMajorMatrixXf = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

Eigen::VectorXf RandomUnitVector(Random& random, int dim) {
  Eigen::VectorXf v(dim);
  for (int d = 0; d < dim; ++d) v[d] = static_cast<float>(random.Normal());
  return v.normalized();
}

RowMajorMatrixXf RandomUnitRows(int rows, int dim, uint64_t seed) {
  Random random(seed);
  RowMajorMatrixXf matrix(rows, dim);
  for (int r = 0; r < rows; ++r) matrix.row(r) = RandomUnitVector(random, dim).transpose();
  return matrix;
}

// Unit vectors around a number of random centres, as global descriptors of a city cluster
// around its streets.
RowMajorMatrixXf ClusteredUnitRows(int rows, int dim, int num_clusters, float spread,
                                   uint64_t seed) {
  Random random(seed);
  std::vector<Eigen::VectorXf> centres;
  for (int c = 0; c < num_clusters; ++c) centres.push_back(RandomUnitVector(random, dim));
  RowMajorMatrixXf matrix(rows, dim);
  for (int r = 0; r < rows; ++r) {
    const Eigen::VectorXf& centre = centres[random.UniformInt(num_clusters)];
    matrix.row(r) = (centre + spread * RandomUnitVector(random, dim)).normalized().transpose();
  }
  return matrix;
}

// Exact top-k by inner product, best first.
std::vector<RetrievalHit> BruteForce(const RowMajorMatrixXf& database, const Eigen::VectorXf& query,
                                     int k) {
  const Eigen::VectorXf scores = database * query;
  std::vector<uint32_t> order(database.rows());
  std::iota(order.begin(), order.end(), 0u);
  k = std::min<int>(k, static_cast<int>(order.size()));
  std::partial_sort(order.begin(), order.begin() + k, order.end(),
                    [&](uint32_t a, uint32_t b) { return scores[a] > scores[b]; });
  std::vector<RetrievalHit> hits;
  for (int i = 0; i < k; ++i) hits.push_back({order[i], scores[order[i]]});
  return hits;
}

std::string Serialize(const GlobalIndex& index) {
  std::ostringstream stream;
  index.Write(stream);
  return stream.str();
}

GlobalIndex Deserialize(const std::string& bytes) {
  std::istringstream stream(bytes);
  return GlobalIndex::Read(stream, "global.index");
}

GlobalIndexOptions IvfPqOptions(int ivf_lists, int pq_subquantizers, int nprobe) {
  GlobalIndexOptions options;
  options.type = GlobalIndexOptions::Type::kIvfPq;
  options.ivf_lists = ivf_lists;
  options.pq_subquantizers = pq_subquantizers;
  options.nprobe = nprobe;
  return options;
}

TEST(GlobalIndexOptionsTest, CheckNamesTheField) {
  const auto expect_message = [](const GlobalIndexOptions& options, const std::string& field) {
    try {
      options.Check();
      ADD_FAILURE() << "no exception for " << field;
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), HasSubstr(field));
    }
  };
  EXPECT_NO_THROW(GlobalIndexOptions().Check());
  expect_message(IvfPqOptions(0, 8, 4), "ivf_lists");
  expect_message(IvfPqOptions(16, 0, 4), "pq_subquantizers");
  expect_message(IvfPqOptions(16, 8, 0), "nprobe");
}

TEST(GlobalIndexTest, FlatSearchEqualsBruteForce) {
  const RowMajorMatrixXf database = RandomUnitRows(500, 64, 1);
  const GlobalIndex index = GlobalIndex::Build(database);
  EXPECT_EQ(index.dimension(), 64);
  EXPECT_EQ(index.size(), 500u);
  Random random(2);
  for (int q = 0; q < 25; ++q) {
    const Eigen::VectorXf query = RandomUnitVector(random, 64);
    const std::vector<RetrievalHit> hits = index.Search(query, 10);
    const std::vector<RetrievalHit> expected = BruteForce(database, query, 10);
    ASSERT_EQ(hits.size(), expected.size());
    for (size_t i = 0; i < hits.size(); ++i) {
      EXPECT_EQ(hits[i].image_index, expected[i].image_index) << "query " << q << " rank " << i;
      EXPECT_NEAR(hits[i].score, expected[i].score, 1e-5f);
    }
  }
}

TEST(GlobalIndexTest, KLargerThanTheIndexReturnsEveryImageBestFirst) {
  const RowMajorMatrixXf database = RandomUnitRows(7, 16, 3);
  const GlobalIndex index = GlobalIndex::Build(database);
  Random random(4);
  const Eigen::VectorXf query = RandomUnitVector(random, 16);
  const std::vector<RetrievalHit> hits = index.Search(query, 100);
  ASSERT_EQ(hits.size(), 7u);
  for (size_t i = 1; i < hits.size(); ++i) EXPECT_GE(hits[i - 1].score, hits[i].score);
  std::vector<uint32_t> ids;
  for (const RetrievalHit& hit : hits) ids.push_back(hit.image_index);
  std::sort(ids.begin(), ids.end());
  EXPECT_EQ(ids, std::vector<uint32_t>({0, 1, 2, 3, 4, 5, 6}));
  EXPECT_TRUE(index.Search(query, 0).empty());
}

// Equal scores rank by image index, so that a search gives the same order on every machine.
TEST(GlobalIndexTest, EqualScoresRankTheLowerImageFirst) {
  RowMajorMatrixXf database = RandomUnitRows(12, 32, 9);
  database.row(9) = database.row(2);
  database.row(5) = database.row(2);
  const GlobalIndex index = GlobalIndex::Build(database);
  const Eigen::VectorXf query = database.row(2).transpose();
  const std::vector<RetrievalHit> hits = index.Search(query, 3);
  ASSERT_EQ(hits.size(), 3u);
  EXPECT_EQ(hits[0].image_index, 2u);
  EXPECT_EQ(hits[1].image_index, 5u);
  EXPECT_EQ(hits[2].image_index, 9u);
  EXPECT_EQ(hits[0].score, hits[2].score);
}

TEST(GlobalIndexTest, ADatabaseImageFindsItselfFirst) {
  const RowMajorMatrixXf database = RandomUnitRows(200, 32, 5);
  const GlobalIndex index = GlobalIndex::Build(database);
  for (uint32_t i = 0; i < 200; i += 13) {
    const std::vector<RetrievalHit> hits = index.Search(database.row(i).transpose(), 1);
    ASSERT_EQ(hits.size(), 1u);
    EXPECT_EQ(hits[0].image_index, i);
    EXPECT_NEAR(hits[0].score, 1.0f, 1e-5f);
  }
}

TEST(GlobalIndexTest, IvfPqRecallAgainstExactSearch) {
  constexpr int kDim = 64;
  const RowMajorMatrixXf database = ClusteredUnitRows(10000, kDim, 200, 0.8f, 6);
  const GlobalIndex index = GlobalIndex::Build(database, IvfPqOptions(128, 8, 16));
  EXPECT_EQ(index.size(), 10000u);
  // Queries are noisy copies of database images, as a query photo is of its place.
  Random random(7);
  constexpr int kQueries = 200;
  int nearest_in_top10 = 0;
  int top10_overlap = 0;
  for (int q = 0; q < kQueries; ++q) {
    const Eigen::VectorXf query = (database.row(random.UniformInt(database.rows())).transpose() +
                                   0.3f * RandomUnitVector(random, kDim))
                                      .normalized();
    const std::vector<RetrievalHit> exact = BruteForce(database, query, 10);
    const std::vector<RetrievalHit> approximate = index.Search(query, 10);
    ASSERT_LE(approximate.size(), 10u);
    for (size_t i = 1; i < approximate.size(); ++i) {
      EXPECT_GE(approximate[i - 1].score, approximate[i].score);
    }
    for (const RetrievalHit& hit : approximate) {
      nearest_in_top10 += hit.image_index == exact[0].image_index;
      for (const RetrievalHit& truth : exact) top10_overlap += hit.image_index == truth.image_index;
    }
  }
  const double recall_at_10 = static_cast<double>(nearest_in_top10) / kQueries;
  const double overlap_at_10 = static_cast<double>(top10_overlap) / (10 * kQueries);
  RecordProperty("ivfpq_1_recall_at_10", std::to_string(recall_at_10));
  RecordProperty("ivfpq_10_recall_at_10", std::to_string(overlap_at_10));
  EXPECT_GE(recall_at_10, 0.9);
  EXPECT_GE(overlap_at_10, 0.4);
}

TEST(GlobalIndexTest, WriteReadRoundTrip) {
  const RowMajorMatrixXf database = ClusteredUnitRows(2000, 32, 50, 0.6f, 8);
  for (const GlobalIndexOptions& options : {GlobalIndexOptions(), IvfPqOptions(32, 8, 4)}) {
    const GlobalIndex index = GlobalIndex::Build(database, options);
    const std::string bytes = Serialize(index);
    const GlobalIndex read = Deserialize(bytes);
    EXPECT_EQ(read.dimension(), index.dimension());
    EXPECT_EQ(read.size(), index.size());
    EXPECT_EQ(read.options().type, options.type);
    EXPECT_EQ(read.options().nprobe, options.nprobe);
    EXPECT_EQ(Serialize(read), bytes);
    Random random(9);
    for (int q = 0; q < 10; ++q) {
      const Eigen::VectorXf query = RandomUnitVector(random, 32);
      const std::vector<RetrievalHit> before = index.Search(query, 5);
      const std::vector<RetrievalHit> after = read.Search(query, 5);
      ASSERT_EQ(before.size(), after.size());
      for (size_t i = 0; i < before.size(); ++i) {
        EXPECT_EQ(before[i].image_index, after[i].image_index);
        EXPECT_EQ(before[i].score, after[i].score);
      }
    }
  }
}

TEST(GlobalIndexTest, ReadRejectsCorruptDataAndNamesTheSource) {
  const std::string bytes = Serialize(GlobalIndex::Build(RandomUnitRows(20, 8, 10)));
  const auto expect_error = [](const std::string& corrupt, const std::string& expected) {
    try {
      Deserialize(corrupt);
      ADD_FAILURE() << "no exception, expected " << expected;
    } catch (const std::invalid_argument& error) {
      EXPECT_THAT(error.what(), HasSubstr("global.index"));
      EXPECT_THAT(error.what(), HasSubstr(expected));
    }
  };
  expect_error("", "truncated");
  std::string bad_magic = bytes;
  bad_magic[1] = 'X';
  expect_error(bad_magic, "magic");
  std::string bad_version = bytes;
  bad_version[8] = 3;
  expect_error(bad_version, "version");
  std::string bad_type = bytes;
  bad_type[12] = 5;
  expect_error(bad_type, "type");
  for (const size_t length : {size_t{20}, size_t{44}, bytes.size() / 2, bytes.size() - 1}) {
    expect_error(bytes.substr(0, length), "truncated");
  }
  // The header's length covers the FAISS bytes, which are garbage.
  constexpr size_t kHeaderBytes = 48;
  std::string garbage = bytes;
  std::fill(garbage.begin() + kHeaderBytes, garbage.end(), 'z');
  expect_error(garbage, "FAISS");
  // A header that disagrees with the FAISS index it carries.
  std::string wrong_size = bytes;
  wrong_size[32] = 21;
  expect_error(wrong_size, "header says");
}

TEST(GlobalIndexTest, BadInputsThrow) {
  const RowMajorMatrixXf database = RandomUnitRows(300, 24, 11);
  const GlobalIndex index = GlobalIndex::Build(database);
  try {
    index.Search(Eigen::VectorXf::Ones(16), 3);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("16"));
    EXPECT_THAT(error.what(), HasSubstr("24"));
  }
  Eigen::VectorXf nan_query = database.row(0).transpose();
  nan_query[2] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(index.Search(nan_query, 3), std::invalid_argument);
  nan_query[2] = std::numeric_limits<float>::infinity();
  EXPECT_THROW(index.Search(nan_query, 3), std::invalid_argument);
  EXPECT_THROW(index.Search(database.row(0).transpose(), -1), std::invalid_argument);

  RowMajorMatrixXf bad_database = database;
  bad_database(5, 5) = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(GlobalIndex::Build(bad_database), std::invalid_argument);
  try {
    GlobalIndex::Build(database, IvfPqOptions(4, 7, 2));
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("pq_subquantizers = 7"));
  }
  try {
    GlobalIndex::Build(RandomUnitRows(100, 24, 12), IvfPqOptions(4, 8, 2));
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("256"));
  }
  EXPECT_THROW(GlobalIndex::Build(database, IvfPqOptions(0, 8, 2)), std::invalid_argument);
}

TEST(GlobalIndexTest, EmptyIndexHasNoDimension) {
  const GlobalIndex empty;
  EXPECT_EQ(empty.dimension(), 0);
  EXPECT_EQ(empty.size(), 0u);
  EXPECT_THROW(empty.Search(Eigen::VectorXf::Ones(4), 1), std::invalid_argument);
  std::ostringstream stream;
  EXPECT_THROW(empty.Write(stream), std::invalid_argument);
}

TEST(GlobalIndexTest, ConcurrentSearchesMatchSerialOnes) {
  const RowMajorMatrixXf database = ClusteredUnitRows(3000, 32, 60, 0.6f, 13);
  for (const GlobalIndexOptions& options : {GlobalIndexOptions(), IvfPqOptions(32, 8, 4)}) {
    const GlobalIndex index = GlobalIndex::Build(database, options);
    const RowMajorMatrixXf queries = RandomUnitRows(64, 32, 14);
    std::vector<std::vector<RetrievalHit>> serial;
    for (Eigen::Index q = 0; q < queries.rows(); ++q) {
      serial.push_back(index.Search(queries.row(q).transpose(), 10));
    }
    constexpr int kThreads = 4;
    std::vector<std::vector<std::vector<RetrievalHit>>> parallel(kThreads);
    std::vector<std::thread> threads;
    for (int t = 0; t < kThreads; ++t) {
      threads.emplace_back([&, t] {
        for (Eigen::Index q = 0; q < queries.rows(); ++q) {
          parallel[t].push_back(index.Search(queries.row(q).transpose(), 10));
        }
      });
    }
    for (std::thread& thread : threads) thread.join();
    for (int t = 0; t < kThreads; ++t) {
      ASSERT_EQ(parallel[t].size(), serial.size());
      for (size_t q = 0; q < serial.size(); ++q) {
        ASSERT_EQ(parallel[t][q].size(), serial[q].size());
        for (size_t i = 0; i < serial[q].size(); ++i) {
          EXPECT_EQ(parallel[t][q][i].image_index, serial[q][i].image_index);
          EXPECT_EQ(parallel[t][q][i].score, serial[q][i].score);
        }
      }
    }
  }
}

}  // namespace
}  // namespace hscloc
