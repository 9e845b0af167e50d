// Image retrieval on the synthetic city: VLAD trained on the database images' features, a flat
// index over them, day and night queries against it.
#include <gtest/gtest.h>

#include <algorithm>
#include <iostream>
#include <string>

#include "retrieval/global_index.h"
#include "retrieval/vlad.h"
#include "synthetic/synthetic_city.h"
#include "util/parallel.h"

namespace hscloc {
namespace {

// A retrieved database image is right for a query when the two see at least this many common
// city points: enough 2D-3D matches for the pose stage to have something to work with (PnP
// needs 4, RANSAC wants a margin), where a handful of shared points would count a view that
// only grazes the query's scene.
constexpr size_t kMinSharedPoints = 20;

// Query feature streams are keyed apart from the database's (keyed by the view index).
constexpr uint64_t kDayQueryKey = uint64_t{1} << 48;
constexpr uint64_t kNightQueryKey = uint64_t{2} << 48;

size_t CountShared(const std::vector<uint32_t>& a, const std::vector<uint32_t>& b) {
  size_t count = 0;
  auto i = a.begin();
  auto j = b.begin();
  while (i != a.end() && j != b.end()) {
    if (*i < *j) {
      ++i;
    } else if (*j < *i) {
      ++j;
    } else {
      ++count;
      ++i;
      ++j;
    }
  }
  return count;
}

struct RecallAtK {
  double at1 = 0;
  double at5 = 0;
  double at10 = 0;
};

class RetrievalCityTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    city_ = new SyntheticCity(SyntheticCityOptions::Preset("small"));
    const std::vector<SyntheticView>& views = city_->database_views();
    database_features_.resize(views.size());
    database_points_.resize(views.size());
    ParallelFor(views.size(), 0, [](size_t begin, size_t end) {
      const std::vector<SyntheticView>& views = city_->database_views();
      for (size_t i = begin; i < end; ++i) {
        database_features_[i] =
            city_->MakeViewFeatures(views[i], QueryCondition::kDay, i).features.descriptors;
        database_points_[i] = city_->VisiblePoints(views[i].camera, views[i].cam_from_world);
      }
    });
  }

  static void TearDownTestSuite() {
    delete city_;
    city_ = nullptr;
    database_features_.clear();
    database_points_.clear();
  }

  // The share of queries with a right database image among the first 1, 5 and 10 retrieved.
  static RecallAtK Evaluate(const VladEncoder& encoder, const GlobalIndex& index,
                            QueryCondition condition) {
    const std::vector<SyntheticView>& queries = city_->queries(condition);
    const uint64_t key = condition == QueryCondition::kDay ? kDayQueryKey : kNightQueryKey;
    std::vector<int> first_right_rank(queries.size(), -1);
    ParallelFor(queries.size(), 0, [&](size_t begin, size_t end) {
      for (size_t q = begin; q < end; ++q) {
        const SyntheticView& query = queries[q];
        const DescriptorMatrix descriptors =
            city_->MakeViewFeatures(query, condition, key | q).features.descriptors;
        const std::vector<uint32_t> seen = city_->VisiblePoints(query.camera, query.cam_from_world);
        const std::vector<RetrievalHit> hits = index.Search(encoder.Encode(descriptors), 10);
        for (size_t rank = 0; rank < hits.size(); ++rank) {
          if (CountShared(seen, database_points_[hits[rank].image_index]) >= kMinSharedPoints) {
            first_right_rank[q] = static_cast<int>(rank);
            break;
          }
        }
      }
    });
    const auto recall = [&](int k) {
      const auto found = std::count_if(first_right_rank.begin(), first_right_rank.end(),
                                       [k](int rank) { return rank >= 0 && rank < k; });
      return static_cast<double>(found) / static_cast<double>(queries.size());
    };
    return {recall(1), recall(5), recall(10)};
  }

  static SyntheticCity* city_;
  static std::vector<DescriptorMatrix> database_features_;
  static std::vector<std::vector<uint32_t>> database_points_;
};

SyntheticCity* RetrievalCityTest::city_ = nullptr;
std::vector<DescriptorMatrix> RetrievalCityTest::database_features_;
std::vector<std::vector<uint32_t>> RetrievalCityTest::database_points_;

TEST_F(RetrievalCityTest, DefaultVladFindsTheDayQueriesPlaces) {
  const VladEncoder encoder = VladEncoder::Train(database_features_, VladOptions());
  // The whitening keeps at most one dimension fewer than it has images.
  ASSERT_EQ(encoder.output_dim(), std::min<int>(VladOptions().whitened_dim,
                                                static_cast<int>(database_features_.size()) - 1));
  DescriptorMatrix descriptors(database_features_.size(), encoder.output_dim());
  ParallelFor(database_features_.size(), 0, [&](size_t begin, size_t end) {
    for (size_t i = begin; i < end; ++i) {
      descriptors.row(i) = encoder.Encode(database_features_[i]).transpose();
    }
  });
  const GlobalIndex index = GlobalIndex::Build(descriptors);

  const RecallAtK day = Evaluate(encoder, index, QueryCondition::kDay);
  const RecallAtK night = Evaluate(encoder, index, QueryCondition::kNight);
  std::cout << "small city, " << database_features_.size() << " database images, default VLAD ("
            << encoder.num_words() << " words, whitened to " << encoder.output_dim()
            << "): recall@1/5/10 day " << day.at1 << " / " << day.at5 << " / " << day.at10
            << ", night " << night.at1 << " / " << night.at5 << " / " << night.at10 << "\n";
  for (const auto& [name, value] : {std::pair<const char*, double>{"day_recall_at_1", day.at1},
                                    {"day_recall_at_5", day.at5},
                                    {"day_recall_at_10", day.at10},
                                    {"night_recall_at_1", night.at1},
                                    {"night_recall_at_5", night.at5},
                                    {"night_recall_at_10", night.at10}}) {
    RecordProperty(name, std::to_string(value));
  }
  EXPECT_GE(day.at10, 0.95);
  // Night queries detect fewer points under stronger noise: a weaker bound that still catches a
  // broken encoder (a query has 3 to 30 right images among 416).
  EXPECT_GE(night.at10, 0.8);
}

}  // namespace
}  // namespace hscloc
