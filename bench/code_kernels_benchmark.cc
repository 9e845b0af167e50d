// The last round's similarity product at aachen's shape: a block of the map points' 8-bit codes
// (D = 256) against a night query's keypoints, as code_kernels::CodeSimilarities computes it,
// beside the float product of the same unit rows (dense_kernels::Linear) that it replaced and
// the portable loop every path equals. The counters give each one's rate in multiply-adds per
// second, so that the ratio to the float product reads off one run.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "model/code_kernels.h"
#include "model/dense_kernels.h"
#include "util/random.h"

namespace hscloc {
namespace {

constexpr int64_t kDimension = 256;

std::vector<float> RandomUnitRows(int64_t rows, Random& random) {
  std::vector<float> values(rows * kDimension);
  for (int64_t row = 0; row < rows; ++row) {
    float* begin = values.data() + row * kDimension;
    double squares = 0.0;
    for (int64_t d = 0; d < kDimension; ++d) {
      begin[d] = static_cast<float>(random.Normal());
      squares += double{begin[d]} * begin[d];
    }
    const auto scale = static_cast<float>(1.0 / std::sqrt(squares));
    for (int64_t d = 0; d < kDimension; ++d) begin[d] *= scale;
  }
  return values;
}

// Rows at 8 bits as map/point_descriptors.h stores them: each value times 127 over the row's
// largest magnitude.
std::vector<int8_t> RowCodes(const std::vector<float>& rows) {
  std::vector<int8_t> codes(rows.size());
  for (size_t first = 0; first < rows.size(); first += kDimension) {
    float largest = 0.0f;
    for (int64_t d = 0; d < kDimension; ++d) largest = std::max(largest, std::abs(rows[first + d]));
    for (int64_t d = 0; d < kDimension; ++d) {
      codes[first + d] = static_cast<int8_t>(std::lround(rows[first + d] / largest * 127.0f));
    }
  }
  return codes;
}

struct Shape {
  int64_t rows;
  int64_t queries;
};

Shape ShapeOf(const benchmark::State& state) { return {state.range(0), state.range(1)}; }

void SetRate(benchmark::State& state, const Shape& shape) {
  state.counters["multiply_adds_per_s"] =
      benchmark::Counter(static_cast<double>(shape.rows * shape.queries * kDimension),
                         benchmark::Counter::kIsIterationInvariantRate);
}

// A block of random unit rows as codes and the queries packed against them.
struct CodeBlock {
  std::vector<int8_t> codes;
  std::vector<float> inverse_norms;
  code_kernels::PackedQueryCodes queries;
  std::vector<float> out;

  explicit CodeBlock(const Shape& shape) {
    Random random(1);
    codes = RowCodes(RandomUnitRows(shape.rows, random));
    const std::vector<float> query_rows = RandomUnitRows(shape.queries, random);
    queries = code_kernels::PackQueryCodes(query_rows.data(), shape.queries, kDimension);
    inverse_norms.resize(shape.rows);
    code_kernels::InverseCodeNorms(codes.data(), shape.rows, kDimension, inverse_norms.data());
    out.resize(shape.rows * queries.padded_count);
  }
};

void BM_CodeSimilarities(benchmark::State& state) {
  const Shape shape = ShapeOf(state);
  CodeBlock block(shape);
  for (auto _ : state) {
    code_kernels::CodeSimilarities(block.codes.data(), block.inverse_norms.data(), shape.rows,
                                   block.queries, block.out.data());
    benchmark::DoNotOptimize(block.out.data());
  }
  SetRate(state, shape);
}

void BM_PortableCodeSimilarities(benchmark::State& state) {
  const Shape shape = ShapeOf(state);
  CodeBlock block(shape);
  for (auto _ : state) {
    code_kernels::PortableCodeSimilarities(block.codes.data(), block.inverse_norms.data(),
                                           shape.rows, block.queries, block.out.data());
    benchmark::DoNotOptimize(block.out.data());
  }
  SetRate(state, shape);
}

// The float product of the same unit rows: the queries are the packed weight, as the similarity
// block is [rows x queries].
void BM_FloatSimilarities(benchmark::State& state) {
  const Shape shape = ShapeOf(state);
  Random random(1);
  const std::vector<float> rows = RandomUnitRows(shape.rows, random);
  const std::vector<float> queries = RandomUnitRows(shape.queries, random);
  const dense_kernels::PackedMatrix packed =
      dense_kernels::PackMatrix(queries.data(), shape.queries, kDimension);
  const std::vector<float> zero_bias(shape.queries, 0.0f);
  std::vector<float> out(shape.rows * shape.queries);
  for (auto _ : state) {
    dense_kernels::Linear(rows.data(), shape.rows, packed, zero_bias.data(), false, out.data());
    benchmark::DoNotOptimize(out.data());
  }
  SetRate(state, shape);
}

// 8,192 of a union's points against a night query (512 keypoints) and the shortlist's sample
// (128 of them).
void Shapes(benchmark::internal::Benchmark* benchmark) {
  benchmark->ArgNames({"rows", "queries"})->Args({8192, 512})->Args({8192, 128});
  benchmark->Unit(benchmark::kMillisecond);
}

BENCHMARK(BM_CodeSimilarities)->Apply(Shapes);
BENCHMARK(BM_FloatSimilarities)->Apply(Shapes);
BENCHMARK(BM_PortableCodeSimilarities)->ArgNames({"rows", "queries"})->Args({1024, 128});

}  // namespace
}  // namespace hscloc
