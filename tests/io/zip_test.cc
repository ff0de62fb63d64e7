#include "framework/io/zip.h"

#include "framework/core/error.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace soma {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::ThrowsMessage;

using Members = std::vector<std::pair<std::string, std::string>>;

Members TestMembers() {
  std::string big;
  for (int i = 0; i < 20000; ++i) big += "abcd" + std::to_string(i % 7);
  return {{"a.txt", "hello zip"},
          {"dir/b.bin", big},
          {"empty", ""},
          {"c.npy", std::string("\x00\x01\xff\x80", 4)}};
}

std::string WriteArchive(const Members& members, ZipWriteOptions options) {
  std::ostringstream out(std::ios::out | std::ios::binary);
  ZipWriter writer(out, options);
  for (const auto& [name, bytes] : members) writer.Add(name, bytes);
  writer.Finish();
  EXPECT_TRUE(out.good());
  return out.str();
}

class ZipRoundTrip : public ::testing::TestWithParam<bool> {};

TEST_P(ZipRoundTrip, ReadsBackEveryMemberInOrder) {
  const bool deflate = GetParam();
  const Members members = TestMembers();
  const std::string archive =
      WriteArchive(members, ZipWriteOptions{.deflate = deflate});
  const ZipReader reader(archive, "mem.zip");
  EXPECT_EQ(reader.source(), "mem.zip");
  ASSERT_EQ(reader.entries().size(), members.size());
  for (size_t i = 0; i < members.size(); ++i) {
    const ZipEntry& entry = reader.entries()[i];
    EXPECT_EQ(entry.name, members[i].first);
    EXPECT_EQ(entry.method, deflate ? 8 : 0);
    EXPECT_EQ(entry.uncompressed_size, members[i].second.size());
    EXPECT_EQ(reader.Read(entry), members[i].second) << entry.name;
  }
  const ZipEntry& big = reader.entries()[1];
  if (deflate) {
    EXPECT_LT(big.compressed_size * 10, big.uncompressed_size);
  } else {
    EXPECT_EQ(big.compressed_size, big.uncompressed_size);
  }
}

INSTANTIATE_TEST_SUITE_P(StoredDeflated,
                         ZipRoundTrip,
                         ::testing::Values(false, true));

TEST(ZipWriter, EqualInputGivesEqualBytes) {
  const ZipWriteOptions options{.deflate = true};
  EXPECT_EQ(WriteArchive(TestMembers(), options),
            WriteArchive(TestMembers(), options));
  EXPECT_NE(WriteArchive(TestMembers(), options),
            WriteArchive(TestMembers(), ZipWriteOptions{}));
}

TEST(ZipReader, CorruptStoredDataIsACrcErrorNamingTheMember) {
  std::string archive = WriteArchive({{"a.txt", "hello zip"}}, {});
  const size_t pos = archive.find("hello zip");
  ASSERT_NE(pos, std::string::npos);
  archive[pos] = 'j';
  const ZipReader reader(archive, "bad.zip");
  EXPECT_THAT([&] { reader.Read(reader.entries().at(0)); },
              ThrowsMessage<IoError>(AllOf(HasSubstr("bad.zip: entry 'a.txt'"),
                                           HasSubstr("CRC-32 mismatch"))));
}

TEST(ZipReader, RejectsNonArchivesAndTruncatedArchives) {
  EXPECT_THAT([] { ZipReader("not a zip at all, no", "x.zip"); },
              ThrowsMessage<IoError>(HasSubstr("x.zip: not a zip archive")));
  const std::string archive = WriteArchive(TestMembers(), {});
  const std::string half = archive.substr(0, archive.size() / 2);
  EXPECT_THAT(
      [&] { ZipReader(half, "t.zip"); },
      ThrowsMessage<IoError>(HasSubstr("t.zip: truncated zip archive")));
}

TEST(ZipReader, CorruptDeflateStreamNamesTheMember) {
  std::string archive =
      WriteArchive({{"big.bin", TestMembers()[1].second}}, {.deflate = true});
  // Inside the compressed data of the only member (local header: 30 bytes
  // plus the name).
  for (size_t i = 60; i < 90; ++i) archive[i] = static_cast<char>(0xFF);
  const ZipReader reader(archive, "bad.zip");
  EXPECT_THAT([&] { reader.Read(reader.entries().at(0)); },
              ThrowsMessage<IoError>(HasSubstr("bad.zip: entry 'big.bin': ")));
}

TEST(ZipReader, CorruptCentralDirectoryIsAnError) {
  std::string archive = WriteArchive(TestMembers(), {});
  const size_t cd = archive.find("PK\x01\x02");
  ASSERT_NE(cd, std::string::npos);
  archive[cd + 2] = 'X';  // break the first record's signature
  EXPECT_THAT([&] { ZipReader(archive, "cd.zip"); },
              ThrowsMessage<IoError>(HasSubstr("cd.zip: ")));
}

TEST(ZipWriter, RejectsBadAndDuplicateNames) {
  std::ostringstream out(std::ios::out | std::ios::binary);
  ZipWriter writer(out);
  writer.Add("a", "1");
  EXPECT_THROW(writer.Add("a", "2"), IoError);
  EXPECT_THROW(writer.Add("", "2"), IoError);
  EXPECT_THROW(writer.Add(std::string(70000, 'n'), "2"), IoError);
}

TEST(ZipWriter, EmptyArchiveIsValid) {
  const std::string archive = WriteArchive({}, {});
  EXPECT_EQ(archive.size(), 22u);
  EXPECT_TRUE(ZipReader(archive, "empty.zip").entries().empty());
}

}  // namespace
}  // namespace soma
