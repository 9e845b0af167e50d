#include "util/binary_io.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <random>
#include <sstream>

namespace hscloc {
namespace {

using ::testing::HasSubstr;

TEST(BinaryIo, RoundTripsValuesArraysAndStrings) {
  std::mt19937 random(7);
  std::uniform_real_distribution<double> uniform(-1e6, 1e6);
  std::stringstream stream;
  const double value = uniform(random);
  const uint64_t count = random();
  std::vector<float> array(37);
  for (float& x : array) x = static_cast<float>(uniform(random));
  WriteBinary(stream, value);
  WriteBinary(stream, count);
  WriteBinaryArray(stream, array.data(), array.size());
  stream.write("name.jpg", 9);  // with its NUL

  EXPECT_EQ(ReadBinary<double>(stream, "value"), value);
  EXPECT_EQ(ReadBinary<uint64_t>(stream, "count"), count);
  std::vector<float> read(array.size());
  ReadBinaryArray(stream, read.data(), read.size(), "array");
  EXPECT_EQ(read, array);
  EXPECT_EQ(ReadBinaryCString(stream, "name"), "name.jpg");
}

TEST(BinaryIo, MemoryInputStreamReadsSeeksAndEndsLikeAStringStream) {
  std::mt19937 random(11);
  std::string bytes(1000, '\0');
  for (char& byte : bytes) byte = static_cast<char>(random());
  MemoryInputStream memory(bytes);
  std::istringstream copy(bytes);
  std::uniform_int_distribution<int> offset(0, 999);
  char from_memory[64];
  char from_copy[64];
  for (int trial = 0; trial < 50; ++trial) {
    const int position = offset(random);
    memory.seekg(position);
    copy.seekg(position);
    EXPECT_EQ(memory.tellg(), copy.tellg());
    memory.read(from_memory, sizeof(from_memory));
    copy.read(from_copy, sizeof(from_copy));
    ASSERT_EQ(memory.gcount(), copy.gcount()) << position;
    EXPECT_EQ(std::string(from_memory, memory.gcount()), std::string(from_copy, copy.gcount()));
    EXPECT_EQ(memory.eof(), copy.eof());
    memory.clear();
    copy.clear();
  }
  memory.seekg(-10, std::ios::end);
  EXPECT_EQ(memory.tellg(), 990);
  memory.seekg(5, std::ios::cur);
  EXPECT_EQ(memory.tellg(), 995);
  memory.seekg(2000);
  EXPECT_TRUE(memory.fail());  // beyond the end
  // The stream reads the caller's bytes in place: a change after it was made shows.
  MemoryInputStream view(bytes);
  bytes[1] = 'Q';
  view.seekg(1);
  EXPECT_EQ(view.peek(), 'Q');
}

TEST(BinaryIo, ShortReadNamesTheRecord) {
  std::stringstream stream(std::string("abc", 3));
  try {
    ReadBinary<uint64_t>(stream, "points3D.bin: point 4 id");
    FAIL() << "expected a truncation error";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("points3D.bin: point 4 id"));
    EXPECT_THAT(error.what(), HasSubstr("8 bytes expected, 3 read"));
  }
}

TEST(BinaryIo, ShortArrayReadThrows) {
  std::stringstream stream(std::string(10, 'x'));
  std::vector<double> values(2);
  EXPECT_THROW(ReadBinaryArray(stream, values.data(), values.size(), "params"),
               std::invalid_argument);
}

TEST(BinaryIo, UnterminatedStringThrows) {
  std::stringstream unterminated(std::string("abc"));
  EXPECT_THROW(ReadBinaryCString(unterminated, "name"), std::invalid_argument);
  std::stringstream too_long(std::string(100, 'a') + '\0');
  EXPECT_THROW(ReadBinaryCString(too_long, "name", 10), std::invalid_argument);
}

}  // namespace
}  // namespace hscloc
