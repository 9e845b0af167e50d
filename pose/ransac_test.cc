#include "pose/ransac.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <set>
#include <vector>

#include "util/random.h"

namespace hscloc {
namespace {

constexpr int kSampleSize = 3;

// The data indices of a ranking: rank r is index data_best_first[r], here a fixed permutation so
// that a sampler which mixed ranks and indices up would draw the wrong data.
std::vector<int> ReversedRanking(int num_data) {
  std::vector<int> data_best_first(num_data);
  std::iota(data_best_first.rbegin(), data_best_first.rend(), 0);
  return data_best_first;
}

int RankOf(int index, int num_data) { return num_data - 1 - index; }

TEST(ProgressiveSampler, StartsWithTheBestAndAddsEachNewcomerToItsDraws) {
  const int num_data = 200;
  const int growth_samples = 5000;
  const std::vector<int> ranking = ReversedRanking(num_data);
  ProgressiveSampler<kSampleSize> sampler(ranking, growth_samples);
  Random random(3);
  const auto first = sampler.Draw(random);
  std::set<int> first_ranks;
  for (const int index : first) first_ranks.insert(RankOf(index, num_data));
  EXPECT_EQ(first_ranks, (std::set<int>{0, 1, 2}));

  int previous_prefix = sampler.prefix();
  int draws = 1;
  while (sampler.prefix() < num_data) {
    const auto sample = sampler.Draw(random);
    ++draws;
    ASSERT_LE(draws, growth_samples + num_data) << "the prefix never reached all the data";
    ASSERT_GE(sampler.prefix(), previous_prefix);
    previous_prefix = sampler.prefix();
    std::set<int> ranks;
    for (const int index : sample) {
      ASSERT_GE(index, 0);
      ASSERT_LT(index, num_data);
      ranks.insert(RankOf(index, num_data));
    }
    ASSERT_EQ(ranks.size(), 3u) << "a sample holds three different data";
    EXPECT_LT(*ranks.rbegin(), sampler.prefix()) << "drawn beyond the prefix";
    EXPECT_TRUE(ranks.count(sampler.prefix() - 1)) << "a growing prefix's draw holds its newest";
  }
  // The prefix spans every datum about when uniform draws over growth_samples would have drawn
  // each triple of it as often.
  EXPECT_GT(draws, growth_samples / 2);

  // Past the growth, the draws are uniform over all the data.
  std::vector<int> drawn(num_data, 0);
  for (int i = 0; i < 20000; ++i) {
    for (const int index : sampler.Draw(random)) ++drawn[index];
  }
  const auto [least, most] = std::minmax_element(drawn.begin(), drawn.end());
  const double mean = 3.0 * 20000 / num_data;
  EXPECT_GT(*least, 0.7 * mean);
  EXPECT_LT(*most, 1.3 * mean);
}

// The first draws favour the best-ranked data far beyond what uniform draws would.
TEST(ProgressiveSampler, DrawsFromTheBestRankedFirst) {
  const int num_data = 400;
  const int growth_samples = 5000;
  const std::vector<int> ranking = ReversedRanking(num_data);
  ProgressiveSampler<kSampleSize> sampler(ranking, growth_samples);
  Random random(4);
  const int best = num_data / 4;
  int within_best = 0;
  const int draws = 500;
  for (int i = 0; i < draws; ++i) {
    const auto sample = sampler.Draw(random);
    within_best += std::all_of(sample.begin(), sample.end(),
                               [&](int index) { return RankOf(index, num_data) < best; });
  }
  const double uniform_expected = draws * std::pow(static_cast<double>(best) / num_data, 3);
  EXPECT_GT(within_best, 5 * uniform_expected);
}

}  // namespace
}  // namespace hscloc
