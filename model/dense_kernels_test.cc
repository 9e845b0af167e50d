#include "model/dense_kernels.h"

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "util/random.h"
#include "util/testing.h"

namespace hscloc {
namespace {

using RowMajor = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

using testing::NormalFloats;

float EluReference(float x) { return x > 0 ? x : std::expm1(x); }

// The softmax of `rows` rows of logits, each value through its row's normalizer.
std::vector<float> SoftmaxRows(const float* logits, int64_t rows, int64_t columns) {
  std::vector<dense_kernels::SoftmaxNormalizer> normalizers(rows);
  dense_kernels::SoftmaxNormalizers(logits, rows, columns, normalizers.data());
  std::vector<float> probabilities(rows * columns);
  for (int64_t r = 0; r < rows; ++r) {
    for (int64_t c = 0; c < columns; ++c) {
      probabilities[r * columns + c] =
          dense_kernels::SoftmaxOf(logits[r * columns + c], normalizers[r]);
    }
  }
  return probabilities;
}

TEST(DenseKernelsTest, LinearMatchesAReferenceProductForAnyShape) {
  Random random(1);
  for (int64_t m : {1, 3, 17, 128}) {
    for (int64_t k : {5, 16, 40}) {
      for (int64_t n : {1, 12, 100}) {
        for (bool elu : {false, true}) {
          const std::vector<float> in = NormalFloats(m * k, random);
          const std::vector<float> weight = NormalFloats(n * k, random);
          const std::vector<float> bias = NormalFloats(n, random);
          std::vector<float> out(m * n);
          dense_kernels::Linear(in.data(), m, dense_kernels::PackMatrix(weight.data(), n, k),
                                bias.data(), elu, out.data());
          RowMajor expected = Eigen::Map<const RowMajor>(in.data(), m, k) *
                              Eigen::Map<const RowMajor>(weight.data(), n, k).transpose();
          expected.rowwise() += Eigen::Map<const Eigen::RowVectorXf>(bias.data(), n);
          if (elu) expected = expected.unaryExpr(&EluReference);
          const float error =
              (Eigen::Map<const RowMajor>(out.data(), m, n) - expected).cwiseAbs().maxCoeff();
          EXPECT_LT(error, 1e-4f * std::sqrt(float(k))) << m << "x" << k << "x" << n;
        }
      }
    }
  }
}

// Each output of the packed product is the chain fma(x_k, w_k, ...) over k in order, then the
// bias: std::fma rounds once as the hardware instruction does, so where the kernels have FMA the
// result is that chain to the bit, whatever the row's place in its tile or the panel's padding.
TEST(DenseKernelsTest, PackedLinearIsTheOrderedFusedChainOfEveryOutput) {
  Random random(3);
  const bool fused =
      std::string(dense_kernels::KernelInstructionSets()).find("FMA") != std::string::npos;
  const int64_t panel = dense_kernels::PanelWidth();
  for (int64_t m : {1, 5, 12, 13, 29}) {
    for (int64_t k : {1, 7, 64}) {
      for (int64_t n : {int64_t{1}, panel - 1, panel, panel + 3, 2 * panel + 5}) {
        const std::vector<float> in = NormalFloats(m * k, random);
        const std::vector<float> weight = NormalFloats(n * k, random);
        const std::vector<float> bias = NormalFloats(n, random);
        const dense_kernels::PackedMatrix packed = dense_kernels::PackMatrix(weight.data(), n, k);
        for (bool elu : {false, true}) {
          std::vector<float> out(m * n, std::numeric_limits<float>::quiet_NaN());
          dense_kernels::Linear(in.data(), m, packed, bias.data(), elu, out.data());
          for (int64_t row = 0; row < m; ++row) {
            for (int64_t column = 0; column < n; ++column) {
              float chain = 0;
              for (int64_t i = 0; i < k; ++i) {
                chain = std::fma(in[row * k + i], weight[column * k + i], chain);
              }
              chain += bias[column];
              const float got = out[row * n + column];
              if (elu) {
                EXPECT_NEAR(got, EluReference(chain), 1e-5f * (1 + std::abs(chain)));
              } else if (fused) {
                EXPECT_EQ(got, chain)
                    << m << "x" << k << "x" << n << " at " << row << ", " << column;
              } else {
                EXPECT_NEAR(got, chain, 1e-4f * std::sqrt(float(k)));
              }
            }
          }
        }
      }
    }
  }
}

// A row's outputs do not depend on the rows beside it: the product of one row alone is the same
// bits as that row's place in a block of many.
TEST(DenseKernelsTest, PackedLinearGivesARowTheSameBitsAloneAsInABlock) {
  Random random(4);
  const int64_t m = 31, k = 96, n = 70;
  const std::vector<float> in = NormalFloats(m * k, random);
  const std::vector<float> weight = NormalFloats(n * k, random);
  const std::vector<float> bias = NormalFloats(n, random);
  const dense_kernels::PackedMatrix packed = dense_kernels::PackMatrix(weight.data(), n, k);
  std::vector<float> block(m * n);
  dense_kernels::Linear(in.data(), m, packed, bias.data(), true, block.data());
  for (int64_t row = 0; row < m; ++row) {
    std::vector<float> alone(n);
    dense_kernels::Linear(in.data() + row * k, 1, packed, bias.data(), true, alone.data());
    EXPECT_TRUE(std::equal(alone.begin(), alone.end(), block.begin() + row * n)) << row;
  }
}

TEST(DenseKernelsTest, ModulateEluGathersRowsAndModulates) {
  Random random(2);
  const int64_t columns = 37;  // not a multiple of any vector width: exercises the tail
  const std::vector<float> source = NormalFloats(6 * columns, random);
  const std::vector<float> gamma = NormalFloats(3 * columns, random);
  const std::vector<float> beta = NormalFloats(3 * columns, random);
  const std::vector<int64_t> source_rows = {5, 0, 5, 2};
  const std::vector<int32_t> modulation_rows = {2, 2, 0, 1};
  std::vector<float> out(4 * columns);
  dense_kernels::ModulateElu(source.data(), source_rows.data(), gamma.data(), beta.data(),
                             modulation_rows.data(), 4, columns, out.data());
  for (int64_t r = 0; r < 4; ++r) {
    for (int64_t i = 0; i < columns; ++i) {
      const int64_t g = modulation_rows[r] * columns + i;
      const float expected =
          EluReference(gamma[g] * source[source_rows[r] * columns + i] + beta[g]);
      EXPECT_NEAR(out[r * columns + i], expected, 1e-5f) << r << ", " << i;
    }
  }
}

// ELU's negative side is exp(x) - 1 over the whole float range: within a few ulps of expm1's
// -1 .. 0 wherever exp(x) is a normal float, -1 below, never a NaN.
TEST(DenseKernelsTest, EluFollowsExpm1OverTheWholeNegativeRange) {
  std::vector<float> values;
  for (float x = -1e-7f; x > -120.0f; x *= 1.01f) values.push_back(x);
  for (const float x :
       {0.0f, -0.0f, -87.3f, -87.4f, -88.8f, -1e30f, -std::numeric_limits<float>::infinity()}) {
    values.push_back(x);
  }
  std::vector<float> elu = values;
  dense_kernels::EluInPlace(elu.data(), static_cast<int64_t>(elu.size()));
  for (size_t i = 0; i < values.size(); ++i) {
    const double expected = std::expm1(double{values[i]});
    // exp(x) to a few parts in 10^7 of itself, then 1 subtracted.
    const double tolerance = 4e-7 * std::exp(double{values[i]}) + 1e-7 * std::abs(expected);
    EXPECT_NEAR(elu[i], expected, std::max(tolerance, 1e-37)) << values[i];
  }
}

// Candidates scanned in order: each query keeps its best and second-best value and the first
// candidate with the best, as a scalar scan does; ties included, at lengths that leave a tail.
TEST(DenseKernelsTest, UpdateBestTwoKeepsWhatAScanInOrderKeeps) {
  Random random(5);
  for (const int64_t count : {1, 7, 8, 17, 64, 100}) {
    constexpr float kNone = -std::numeric_limits<float>::infinity();
    std::vector<float> best(count, kNone), second(count, kNone);
    std::vector<int32_t> best_index(count, -1);
    std::vector<float> expected_best(count, kNone), expected_second(count, kNone);
    std::vector<int32_t> expected_index(count, -1);
    for (int32_t candidate = 0; candidate < 12; ++candidate) {
      std::vector<float> values(count);
      // Seven distinct values: many ties.
      for (float& value : values) value = 0.25f * static_cast<float>(random.UniformInt(7));
      dense_kernels::UpdateBestTwo(values.data(), count, candidate, best.data(), second.data(),
                                   best_index.data());
      for (int64_t q = 0; q < count; ++q) {
        if (values[q] > expected_best[q]) {
          expected_second[q] = expected_best[q];
          expected_best[q] = values[q];
          expected_index[q] = candidate;
        } else if (values[q] > expected_second[q]) {
          expected_second[q] = values[q];
        }
      }
    }
    EXPECT_EQ(best, expected_best) << count;
    EXPECT_EQ(second, expected_second) << count;
    EXPECT_EQ(best_index, expected_index) << count;
  }
}

TEST(DenseKernelsTest, FirstArgMaxFindsTheFirstOfEqualLargest) {
  std::vector<float> values(37, -1.0f);
  EXPECT_EQ(dense_kernels::FirstArgMax(values.data(), 37), 0);
  values[30] = 2.0f;
  values[35] = 2.0f;
  EXPECT_EQ(dense_kernels::FirstArgMax(values.data(), 37), 30);
  values[9] = 2.0f;
  EXPECT_EQ(dense_kernels::FirstArgMax(values.data(), 37), 9);
  EXPECT_EQ(dense_kernels::FirstArgMax(values.data(), 5), 0);
  // Few distinct values, so that ties fall within packets, across them and in the tail.
  Random random(3);
  for (int64_t count = 1; count <= 70; ++count) {
    for (int trial = 0; trial < 20; ++trial) {
      std::vector<float> ties(count);
      for (float& value : ties) value = static_cast<float>(random.UniformInt(4));
      EXPECT_EQ(dense_kernels::FirstArgMax(ties.data(), count),
                std::max_element(ties.begin(), ties.end()) - ties.begin())
          << count << ", trial " << trial;
    }
  }
}

// Softmax of logits far below the largest: exp(x - max) can underflow, and no value leaves [0, 1]
// or turns the row into NaN.
TEST(DenseKernelsTest, SoftmaxRowsOfDistantLogitsStayProbabilities) {
  const float minus_infinity = -std::numeric_limits<float>::infinity();
  std::vector<float> row = {0.0f, -10.0f, -90.0f, minus_infinity, -200.0f, 3.0f, -1e30f};
  const std::vector<float> logits = row;
  row = SoftmaxRows(logits.data(), 1, static_cast<int64_t>(logits.size()));
  double reference_sum = 0;
  for (const float value : logits) reference_sum += std::exp(double{value} - 3.0);
  for (size_t i = 0; i < row.size(); ++i) {
    EXPECT_GE(row[i], 0.0f) << i;
    EXPECT_NEAR(row[i], std::exp(double{logits[i]} - 3.0) / reference_sum, 1e-6) << i;
  }
}

TEST(DenseKernelsTest, SoftmaxRowsArePositiveAndSumToOne) {
  Random random(3);
  const int64_t rows = 5;
  const int64_t columns = 100;
  std::vector<float> logits = NormalFloats(rows * columns, random);
  logits[7] = 80;  // large logits must not overflow
  const std::vector<float> values = SoftmaxRows(logits.data(), rows, columns);
  for (int64_t r = 0; r < rows; ++r) {
    const float* row = values.data() + r * columns;
    double sum = 0;
    for (int64_t i = 0; i < columns; ++i) {
      EXPECT_GE(row[i], 0);
      sum += row[i];
    }
    EXPECT_NEAR(sum, 1.0, 1e-5);
    const int64_t argmax_in =
        std::max_element(logits.begin() + r * columns, logits.begin() + (r + 1) * columns) -
        (logits.begin() + r * columns);
    EXPECT_EQ(std::max_element(row, row + columns) - row, argmax_in);
  }
}

// Children a parent does not have come as trailing -inf: they get exactly 0, and the others the
// softmax of the live prefix alone, to the bit.
TEST(DenseKernelsTest, SoftmaxRowsGiveTrailingMissingValuesNothing) {
  Random random(5);
  const int64_t columns = 100;
  for (const int64_t live : {1, 5, 16, 17, 40, 99}) {
    SCOPED_TRACE(::testing::Message() << live << " live columns");
    std::vector<float> row = NormalFloats(columns, random);
    std::fill(row.begin() + live, row.end(), -std::numeric_limits<float>::infinity());
    std::vector<float> prefix(row.begin(), row.begin() + live);
    double reference_sum = 0;
    for (const float value : prefix) reference_sum += std::exp(double{value});
    const std::vector<float> logits = prefix;
    row = SoftmaxRows(row.data(), 1, columns);
    prefix = SoftmaxRows(prefix.data(), 1, live);
    for (int64_t i = 0; i < columns; ++i) {
      if (i >= live) {
        EXPECT_EQ(row[i], 0.0f) << i;
        continue;
      }
      EXPECT_EQ(row[i], prefix[i]) << i;
      EXPECT_NEAR(row[i], std::exp(double{logits[i]}) / reference_sum, 1e-6) << i;
    }
  }
}

using PoolingKernel = decltype(&dense_kernels::PooledMaxLogits);

// Every number of inputs (packet multiples, tails, fewer than a packet), segments of one to sixteen
// rows (the eight- and four-row steps and their tails; a child may own several segments), any
// width: each child holds the largest pool(scores of a segment's rows) over its segments, the
// scores summed in double as a reference, and an output already above it is left alone.
void ExpectEachChildsBestSegment(PoolingKernel kernel,
                                 const std::function<double(const std::vector<double>&)>& pool) {
  Random random(5);
  const int64_t columns = 12;
  for (const int64_t dim : {1, 3, 16, 33}) {
    for (const int64_t inputs : {1, 5, 16, 17, 40}) {
      const std::vector<float> projected = NormalFloats(inputs * dim, random);
      std::vector<uint32_t> starts = {0};
      std::vector<uint8_t> groups;
      for (int64_t segment = 0; segment < 16; ++segment) {
        starts.push_back(starts.back() + 1 + static_cast<uint32_t>(segment));
        groups.push_back(static_cast<uint8_t>((segment * 5) % columns));
      }
      const std::vector<float> rows = NormalFloats(int64_t{starts.back()} * (dim + 1), random);
      std::vector<float> out(inputs * columns, -std::numeric_limits<float>::infinity());
      const int64_t kept_input = inputs / 2;
      out[kept_input * columns + groups[3]] = 1e6f;
      kernel(projected.data(), inputs, dim, rows.data(), starts.data(), groups.data(),
             static_cast<int64_t>(groups.size()), columns, out.data());
      for (int64_t i = 0; i < inputs; ++i) {
        std::vector<double> expected(columns, -std::numeric_limits<double>::infinity());
        for (size_t k = 0; k < groups.size(); ++k) {
          std::vector<double> scores;
          for (uint32_t p = starts[k]; p < starts[k + 1]; ++p) {
            double score = rows[p * (dim + 1) + dim];
            for (int64_t d = 0; d < dim; ++d) {
              score += double{projected[i * dim + d]} * rows[p * (dim + 1) + d];
            }
            scores.push_back(score);
          }
          expected[groups[k]] = std::max(expected[groups[k]], pool(scores));
        }
        if (i == kept_input) expected[groups[3]] = 1e6;
        for (int64_t c = 0; c < columns; ++c) {
          if (std::isinf(expected[c])) {
            EXPECT_TRUE(std::isinf(out[i * columns + c]) && out[i * columns + c] < 0)
                << "no segment of child " << c;
          } else {
            EXPECT_NEAR(out[i * columns + c], expected[c], 1e-4 * (1 + std::abs(expected[c])))
                << "dim " << dim << ", input " << i << " of " << inputs << ", child " << c;
          }
        }
      }
    }
  }
}

TEST(DenseKernelsTest, PooledMaxLogitsKeepEachSegmentsBestScore) {
  ExpectEachChildsBestSegment(dense_kernels::PooledMaxLogits, [](const std::vector<double>& s) {
    return *std::max_element(s.begin(), s.end());
  });
}

// Segments as points: each scores the log of its rows' summed exponentials.
TEST(DenseKernelsTest, BestPointLogSumExpLogitsKeepEachChildsBestPoint) {
  ExpectEachChildsBestSegment(dense_kernels::BestPointLogSumExpLogits,
                              [](const std::vector<double>& scores) {
                                double sum = 0;
                                for (const double score : scores) sum += std::exp(score);
                                return std::log(sum);
                              });
}

// An input's pooled logits are bit-identical wherever it sits among the inputs (its lane), for
// either pooling.
TEST(DenseKernelsTest, PooledLogitsDoNotDependOnTheInputsPlace) {
  Random random(6);
  const int64_t dim = 16;
  const int64_t columns = 3;
  const std::vector<float> input = NormalFloats(dim, random);
  const std::vector<uint32_t> starts = {0, 7, 8, 20};
  const std::vector<uint8_t> groups = {0, 2, 1};
  const std::vector<float> rows = NormalFloats(20 * (dim + 1), random);
  for (const PoolingKernel kernel :
       {dense_kernels::PooledMaxLogits, dense_kernels::BestPointLogSumExpLogits}) {
    std::vector<float> first;
    for (int64_t place = 0; place < 21; ++place) {
      std::vector<float> projected = NormalFloats(21 * dim, random);
      std::copy(input.begin(), input.end(), projected.begin() + place * dim);
      std::vector<float> out(21 * columns, -std::numeric_limits<float>::infinity());
      kernel(projected.data(), 21, dim, rows.data(), starts.data(), groups.data(), 3, columns,
             out.data());
      const std::vector<float> logits(out.begin() + place * columns,
                                      out.begin() + (place + 1) * columns);
      if (place == 0) first = logits;
      EXPECT_EQ(logits, first) << "input at place " << place;
    }
  }
}

// A row's result must not depend on its address: the same values at every offset within a
// cache line give bit-identical outputs.
TEST(DenseKernelsTest, ResultsDoNotDependOnAlignment) {
  Random random(4);
  const int64_t columns = 100;
  const std::vector<float> row = NormalFloats(columns, random);
  std::vector<float> first_softmax;
  std::vector<float> first_elu;
  for (int offset = 0; offset < 16; ++offset) {
    std::vector<float> buffer(offset + columns);
    std::copy(row.begin(), row.end(), buffer.begin() + offset);
    std::vector<float> elu_buffer = buffer;
    const std::vector<float> softmax = SoftmaxRows(buffer.data() + offset, 1, columns);
    dense_kernels::EluInPlace(elu_buffer.data() + offset, columns);
    const std::vector<float> elu(elu_buffer.begin() + offset, elu_buffer.end());
    if (offset == 0) {
      first_softmax = softmax;
      first_elu = elu;
    }
    EXPECT_EQ(softmax, first_softmax) << "offset " << offset;
    EXPECT_EQ(elu, first_elu) << "offset " << offset;
  }
}

}  // namespace
}  // namespace hscloc
