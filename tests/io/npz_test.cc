#include "framework/io/npz.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <map>
#include <string>
#include <vector>
#include <zlib.h>

namespace soma {
namespace {

// A zip written by CPython's zipfile exactly as numpy.savez_compressed does
// (ZipFile.open(name, 'w', force_zip64=True)): local headers carry sizes
// 0xFFFFFFFF plus a ZIP64 extra field, the central directory 32-bit sizes.
// Members: a.npy '<f8' (2, 2) [[1.5, -2], [3.25, 4]] and kintree.npy '<u4'
// (2, 3) [[4294967295, 0, 1], [0, 1, 2]].
const char kPythonNpz[] =
    "\x50\x4b\x03\x04\x2d\x00\x00\x00\x08\x00\x00\x00\x21\x00\x48\x03"
    "\xdb\x82\xff\xff\xff\xff\xff\xff\xff\xff\x05\x00\x14\x00\x61\x2e"
    "\x6e\x70\x79\x01\x00\x10\x00\xa0\x00\x00\x00\x00\x00\x00\x00\x56"
    "\x00\x00\x00\x00\x00\x00\x00\x9b\xec\x17\xea\x1b\x10\xc9\xc8\x50"
    "\xc6\x50\xad\x9e\x92\x5a\x9c\x5c\xa4\x6e\xa5\xa0\x6e\x93\x66\xa1"
    "\xae\xa3\xa0\x9e\x96\x5f\x54\x52\x94\x98\x17\x9f\x5f\x94\x92\x0a"
    "\x12\x77\x4b\xcc\x29\x4e\x05\x8a\x17\x67\x24\x16\xa4\x02\xf9\x1a"
    "\x46\x3a\x0a\x46\x9a\x3a\x0a\xb5\x0a\x64\x03\x2e\x06\x30\xf8\x61"
    "\x0f\xa1\x19\x0e\x40\x28\x2e\x07\x08\x2d\xe0\x00\x00\x50\x4b\x03"
    "\x04\x2d\x00\x00\x00\x08\x00\x00\x00\x21\x00\x85\x26\x30\xeb\xff"
    "\xff\xff\xff\xff\xff\xff\xff\x0b\x00\x14\x00\x6b\x69\x6e\x74\x72"
    "\x65\x65\x2e\x6e\x70\x79\x01\x00\x10\x00\x98\x00\x00\x00\x00\x00"
    "\x00\x00\x53\x00\x00\x00\x00\x00\x00\x00\x9b\xec\x17\xea\x1b\x10"
    "\xc9\xc8\x50\xc6\x50\xad\x9e\x92\x5a\x9c\x5c\xa4\x6e\xa5\xa0\x6e"
    "\x53\x6a\xa2\xae\xa3\xa0\x9e\x96\x5f\x54\x52\x94\x98\x17\x9f\x5f"
    "\x94\x92\x0a\x12\x77\x4b\xcc\x29\x4e\x05\x8a\x17\x67\x24\x16\xa4"
    "\x02\xf9\x1a\x46\x3a\x0a\xc6\x9a\x3a\x0a\xb5\x0a\x64\x03\xae\xff"
    "\x40\xc0\x00\x04\x8c\x0c\x10\x00\xa2\x99\x80\x18\x00\x50\x4b\x01"
    "\x02\x2d\x03\x2d\x00\x00\x00\x08\x00\x00\x00\x21\x00\x48\x03\xdb"
    "\x82\x56\x00\x00\x00\xa0\x00\x00\x00\x05\x00\x00\x00\x00\x00\x00"
    "\x00\x00\x00\x00\x00\x80\x01\x00\x00\x00\x00\x61\x2e\x6e\x70\x79"
    "\x50\x4b\x01\x02\x2d\x03\x2d\x00\x00\x00\x08\x00\x00\x00\x21\x00"
    "\x85\x26\x30\xeb\x53\x00\x00\x00\x98\x00\x00\x00\x0b\x00\x00\x00"
    "\x00\x00\x00\x00\x00\x00\x00\x00\x80\x01\x8d\x00\x00\x00\x6b\x69"
    "\x6e\x74\x72\x65\x65\x2e\x6e\x70\x79\x50\x4b\x05\x06\x00\x00\x00"
    "\x00\x02\x00\x02\x00\x6c\x00\x00\x00\x1d\x01\x00\x00\x00\x00";
constexpr size_t kPythonNpzSize = sizeof(kPythonNpz) - 1;

// Builds a version-1.0 .npy image from a raw header dict and data bytes.
std::string HandMadeNpy(const std::string& dict,
                        const std::string& data,
                        int major = 1) {
  std::string header = dict;
  const size_t prefix = major == 1 ? 10 : 12;
  while ((prefix + header.size() + 1) % 64 != 0) header += ' ';
  header += '\n';
  std::string out = "\x93NUMPY";
  out += static_cast<char>(major);
  out += '\0';
  const uint32_t len = static_cast<uint32_t>(header.size());
  out.append(reinterpret_cast<const char*>(&len), major == 1 ? 2 : 4);
  return out + header + data;
}

template <typename T>
std::string Bytes(const std::vector<T>& values) {
  return std::string(reinterpret_cast<const char*>(values.data()),
                     values.size() * sizeof(T));
}

std::map<std::string, NpyArray> SampleArrays() {
  std::map<std::string, NpyArray> arrays;
  Eigen::MatrixXd m(3, 4);
  for (int i = 0; i < 12; ++i) m(i / 4, i % 4) = 0.25 * i - 1.0 / 3.0;
  arrays["matrix"] = NpyArray::FromMatrix(m);
  std::vector<float> f(24);  // 2 x 3 x 4
  for (size_t i = 0; i < f.size(); ++i)
    f[i] = static_cast<float>(i) * 0.5f - 3.0f;
  arrays["cube_f4"] = NpyArray::FromFloats({2, 3, 4}, f);
  arrays["i8"] = NpyArray::FromInt64(
      {4}, {-1, 0, std::numeric_limits<int64_t>::max(), 42});
  arrays["i4"] = NpyArray::FromInt32({2, 2}, {-7, 7, 1 << 30, 0});
  arrays["kintree"] =
      NpyArray::FromUInt32({2, 3}, {4294967295u, 0, 1, 0, 1, 2});
  arrays["bytes"] = NpyArray::FromUInt8({3}, {0, 128, 255});
  arrays["mask"] = NpyArray::FromBools({2, 2}, {true, false, false, true});
  arrays["names"] = NpyArray::FromStrings({3}, {"pelvis", "", "k\xc3\xb6rper"});
  arrays["scalar"] = NpyArray::FromDoubles({}, {120.0});
  arrays["empty"] = NpyArray::FromDoubles({0, 3}, {});
  // Large enough that deflate has something to do.
  std::vector<double> big(5000);
  for (size_t i = 0; i < big.size(); ++i) big[i] = static_cast<double>(i % 17);
  arrays["big"] = NpyArray::FromDoubles({1000, 5}, big);
  return arrays;
}

void ExpectSameArrays(const std::map<std::string, NpyArray>& expected,
                      const std::map<std::string, NpyArray>& actual) {
  ASSERT_EQ(expected.size(), actual.size());
  for (const auto& [key, array] : expected) {
    SCOPED_TRACE(key);
    const auto it = actual.find(key);
    ASSERT_NE(it, actual.end());
    EXPECT_EQ(it->second.dtype, array.dtype);
    EXPECT_EQ(it->second.shape, array.shape);
    EXPECT_EQ(it->second.fortran_order, array.fortran_order);
    EXPECT_EQ(it->second.data, array.data);
  }
}

class NpzRoundTrip : public ::testing::TestWithParam<NpzWriteOptions> {};

TEST_P(NpzRoundTrip, PreservesEveryDtypeAndShape) {
  const std::filesystem::path path = testing::CreateTestDir() / "sample.npz";
  const auto arrays = SampleArrays();
  WriteNpz(path, arrays, GetParam());
  const auto loaded = ReadNpz(path);
  ExpectSameArrays(arrays, loaded);

  // Typed accessors.
  EXPECT_EQ(loaded.at("matrix").AsMatrix(), arrays.at("matrix").AsMatrix());
  EXPECT_EQ(loaded.at("kintree").AsInt64(),
            (std::vector<int64_t>{4294967295, 0, 1, 0, 1, 2}));
  EXPECT_EQ(loaded.at("i8").AsInt64()[2], std::numeric_limits<int64_t>::max());
  EXPECT_EQ(loaded.at("names").AsStrings(),
            (std::vector<std::string>{"pelvis", "", "k\xc3\xb6rper"}));
  EXPECT_EQ(loaded.at("names").dtype, "<U6");
  EXPECT_EQ(loaded.at("mask").AsDoubles(), (std::vector<double>{1, 0, 0, 1}));
  EXPECT_EQ(loaded.at("bytes").AsInt64(), (std::vector<int64_t>{0, 128, 255}));
  EXPECT_EQ(loaded.at("scalar").num_elements(), 1);
  EXPECT_EQ(loaded.at("scalar").ShapeString(), "()");
  EXPECT_EQ(loaded.at("scalar").AsDoubles(), std::vector<double>{120.0});
  EXPECT_EQ(loaded.at("empty").ShapeString(), "(0, 3)");
  EXPECT_EQ(loaded.at("cube_f4").AsDoubles()[5], 2.5 - 3.0);
}

INSTANTIATE_TEST_SUITE_P(StoredDeflated,
                         NpzRoundTrip,
                         ::testing::Values(NpzWriteOptions{false},
                                           NpzWriteOptions{true}));

TEST(Npz, DeflatedIsSmallerAndBytesAreDeterministic) {
  const std::filesystem::path dir = testing::CreateTestDir();
  const auto arrays = SampleArrays();
  WriteNpz(dir / "stored.npz", arrays, {.compress = false});
  WriteNpz(dir / "deflated.npz", arrays, {.compress = true});
  WriteNpz(dir / "deflated2.npz", arrays, {.compress = true});
  EXPECT_LT(std::filesystem::file_size(dir / "deflated.npz"),
            std::filesystem::file_size(dir / "stored.npz"));
  EXPECT_EQ(ReadFile(dir / "deflated.npz"), ReadFile(dir / "deflated2.npz"));
  EXPECT_FALSE(std::filesystem::exists(TempPathFor(dir / "deflated.npz")));
}

TEST(Npz, ReadsPythonZipfileWithZip64LocalHeaders) {
  const std::filesystem::path path = testing::CreateTestDir() / "python.npz";
  WriteFileAtomic(path, std::string_view(kPythonNpz, kPythonNpzSize));
  const NpzReader reader(path);
  EXPECT_EQ(reader.Keys(), (std::vector<std::string>{"a", "kintree"}));
  const NpyArray a = reader.Read("a");
  EXPECT_EQ(a.dtype, "<f8");
  EXPECT_EQ(a.AsDoubles(), (std::vector<double>{1.5, -2.0, 3.25, 4.0}));
  const NpyArray k = reader.Read("kintree");
  EXPECT_EQ(k.ShapeString(), "(2, 3)");
  EXPECT_EQ(k.AsInt64(), (std::vector<int64_t>{4294967295, 0, 1, 0, 1, 2}));
}

TEST(Npy, ParsesHandMadeHeaderWithFortranOrder) {
  // 2 x 3 int32 matrix [[1, 2, 3], [4, 5, 6]] stored column-major.
  const std::string npy =
      HandMadeNpy("{'descr': '<i4', 'fortran_order': True, 'shape': (2, 3), }",
                  Bytes(std::vector<int32_t>{1, 4, 2, 5, 3, 6}));
  ASSERT_EQ(npy.size() % 64, 24u);  // 64-byte header + 24 data bytes
  const NpyArray array = ParseNpy(npy, "hand.npy");
  EXPECT_EQ(array.dtype, "<i4");
  EXPECT_TRUE(array.fortran_order);
  EXPECT_EQ(array.shape, (std::vector<int64_t>{2, 3}));
  EXPECT_EQ(array.AsInt64(), (std::vector<int64_t>{1, 2, 3, 4, 5, 6}));
  Eigen::MatrixXd expected(2, 3);
  expected << 1, 2, 3, 4, 5, 6;
  EXPECT_EQ(array.AsMatrix(), expected);
  // Serialising and parsing again keeps the Fortran layout.
  const NpyArray again = ParseNpy(SerializeNpy(array), "again.npy");
  EXPECT_EQ(again.data, array.data);
  EXPECT_TRUE(again.fortran_order);
}

TEST(Npy, ParsesVersion2BigEndianAndPython2Headers) {
  // Version 2.0 (4-byte header length), big-endian doubles, double quotes,
  // Python 2 long suffix, no trailing comma.
  std::string data;
  for (const double v : {1.0, -0.5, 1e300}) {
    uint64_t bits;
    std::memcpy(&bits, &v, 8);
    for (int b = 7; b >= 0; --b)
      data += static_cast<char>((bits >> (8 * b)) & 0xFF);
  }
  const std::string npy = HandMadeNpy(
      "{\"descr\": \">f8\", \"fortran_order\": False, \"shape\": (3L,)}",
      data,
      2);
  const NpyArray array = ParseNpy(npy, "v2.npy");
  EXPECT_EQ(array.dtype, "<f8");
  EXPECT_EQ(array.AsDoubles(), (std::vector<double>{1.0, -0.5, 1e300}));

  // Byte strings and one-character bool code.
  const NpyArray s = ParseNpy(
      HandMadeNpy("{'descr': '|S4', 'fortran_order': False, 'shape': (2,), }",
                  std::string("malefe\0\0", 8)),
      "s.npy");
  EXPECT_EQ(s.AsStrings(), (std::vector<std::string>{"male", "fe"}));
}

TEST(Npy, SerializedHeaderIsNumpyCompatible) {
  const std::string npy =
      SerializeNpy(NpyArray::FromDoubles({5}, {1, 2, 3, 4, 5}));
  EXPECT_EQ(npy.substr(0, 8), std::string("\x93NUMPY\x01\x00", 8));
  const uint16_t header_len =
      static_cast<uint8_t>(npy[8]) | (static_cast<uint8_t>(npy[9]) << 8);
  EXPECT_EQ((10 + header_len) % 64, 0);
  const std::string header = npy.substr(10, header_len);
  EXPECT_EQ(header.rfind(
                "{'descr': '<f8', 'fortran_order': False, 'shape': (5,), }", 0),
            0u);
  EXPECT_EQ(header.back(), '\n');
  EXPECT_EQ(npy.size(), 10 + header_len + 40u);
}

// ---- Bad input.

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const IoError& e) {
    return e.what();
  }
  return "<no IoError>";
}

TEST(NpzErrors, NotAZipNamesTheFile) {
  const std::filesystem::path path = testing::CreateTestDir() / "text.npz";
  WriteFileAtomic(path, "this is not a zip archive at all, just some text\n");
  const std::string message = ErrorOf([&] { ReadNpz(path); });
  EXPECT_NE(message.find(path.string()), std::string::npos) << message;
  EXPECT_NE(message.find("not a zip archive"), std::string::npos) << message;
  EXPECT_NE(
      ErrorOf([&] { ReadNpz(path.string() + ".missing"); }).find(".missing"),
      std::string::npos);
}

TEST(NpzErrors, TruncatedArchive) {
  const std::filesystem::path dir = testing::CreateTestDir();
  WriteNpz(dir / "full.npz", SampleArrays(), {.compress = true});
  const std::string bytes = ReadFile(dir / "full.npz");
  for (const size_t keep : {bytes.size() / 2, bytes.size() - 30, size_t{40}}) {
    WriteFileAtomic(dir / "cut.npz", bytes.substr(0, keep));
    const std::string message = ErrorOf([&] { ReadNpz(dir / "cut.npz"); });
    EXPECT_NE(message.find("cut.npz"), std::string::npos) << message;
    EXPECT_NE(message.find("truncated"), std::string::npos)
        << keep << ": " << message;
  }
}

TEST(Npz, EmptyArchiveRoundTrips) {
  const std::filesystem::path path = testing::CreateTestDir() / "empty.npz";
  WriteNpz(path, {});
  EXPECT_EQ(std::filesystem::file_size(path), 22u);  // end record only
  EXPECT_TRUE(ReadNpz(path).empty());
}

TEST(NpzErrors, CorruptCentralDirectoryNamesTheFile) {
  const std::filesystem::path dir = testing::CreateTestDir();
  WriteNpz(dir / "a.npz", SampleArrays(), {.compress = true});
  std::string bytes = ReadFile(dir / "a.npz");
  // Overwrite the first central-directory record's signature and sizes.
  const size_t cd = bytes.find("PK\x01\x02");
  ASSERT_NE(cd, std::string::npos);
  for (size_t i = cd; i < cd + 30; ++i) bytes[i] = 'X';
  WriteFileAtomic(dir / "bad.npz", bytes);
  const std::string message = ErrorOf([&] { ReadNpz(dir / "bad.npz"); });
  EXPECT_NE(message.find((dir / "bad.npz").string() + ": "), std::string::npos)
      << message;
  EXPECT_NE(message.find("corrupt"), std::string::npos) << message;
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;
}

TEST(NpzErrors, CrcMismatchNamesTheEntry) {
  const std::filesystem::path dir = testing::CreateTestDir();
  WriteNpz(dir / "a.npz",
           {{"weights", NpyArray::FromDoubles({4}, {1, 2, 3, 4})}},
           {.compress = false});
  std::string bytes = ReadFile(dir / "a.npz");
  // The last data byte of the only (stored) member sits just before the
  // central directory: flip a bit of the value 4.0.
  const size_t cd = bytes.find("PK\x01\x02");
  ASSERT_NE(cd, std::string::npos);
  bytes[cd - 2] ^= 0x01;
  WriteFileAtomic(dir / "a.npz", bytes);
  const std::string message = ErrorOf([&] { ReadNpz(dir / "a.npz"); });
  EXPECT_NE(message.find("weights.npy"), std::string::npos) << message;
  EXPECT_NE(message.find("CRC-32 mismatch"), std::string::npos) << message;
}

TEST(NpzErrors, CorruptDeflateStream) {
  const std::filesystem::path dir = testing::CreateTestDir();
  std::vector<double> values(2000);
  for (size_t i = 0; i < values.size(); ++i) values[i] = std::sin(0.1 * i);
  WriteNpz(dir / "a.npz",
           {{"x", NpyArray::FromDoubles({2000}, values)}},
           {.compress = true});
  std::string bytes = ReadFile(dir / "a.npz");
  for (size_t i = 200; i < 260; ++i) bytes[i] = static_cast<char>(0xFF);
  WriteFileAtomic(dir / "a.npz", bytes);
  const std::string message = ErrorOf([&] { ReadNpz(dir / "a.npz"); });
  EXPECT_NE(message.find("x.npy"), std::string::npos) << message;
}

TEST(NpzErrors, WrongShapeForDataSize) {
  // Header promises (3, 4) doubles = 96 bytes, 80 present.
  const std::string npy =
      HandMadeNpy("{'descr': '<f8', 'fortran_order': False, 'shape': (3, 4), }",
                  std::string(80, '\0'));
  const std::string message =
      ErrorOf([&] { ParseNpy(npy, "m.npz: entry 'v.npy'"); });
  EXPECT_NE(message.find("entry 'v.npy'"), std::string::npos) << message;
  EXPECT_NE(message.find("(3, 4)"), std::string::npos) << message;
  EXPECT_NE(message.find("needs 96 bytes, found 80"), std::string::npos)
      << message;
}

TEST(NpzErrors, UnsupportedDtypeNamesFileEntryAndDtype) {
  // An archive whose member joint2num.npy is an object array (as in SMPL-X
  // model files): patch a stored member's descr to 'O' and fix its CRCs.
  const std::filesystem::path dir = testing::CreateTestDir();
  const NpyArray good = NpyArray::FromDoubles({1}, {1.0});
  WriteNpz(dir / "obj.npz",
           {{"good", good}, {"joint2num", good}},
           {.compress = false});
  std::string bytes = ReadFile(dir / "obj.npz");
  const size_t local = bytes.find("joint2num.npy") - 30;
  ASSERT_EQ(bytes.substr(local, 4), "PK\x03\x04");
  const size_t descr = bytes.find("'<f8'", local);
  bytes.replace(descr, 5, "'O'  ");
  const size_t data_start = local + 30 + std::string("joint2num.npy").size();
  const std::string npy = bytes.substr(data_start, SerializeNpy(good).size());
  const uint32_t crc =
      static_cast<uint32_t>(crc32(0L,
                                  reinterpret_cast<const Bytef*>(npy.data()),
                                  static_cast<uInt>(npy.size())));
  std::memcpy(bytes.data() + local + 14, &crc, 4);
  const size_t central = bytes.rfind("joint2num.npy") - 46;
  ASSERT_EQ(bytes.substr(central, 4), "PK\x01\x02");
  std::memcpy(bytes.data() + central + 16, &crc, 4);
  WriteFileAtomic(dir / "obj.npz", bytes);

  const NpzReader reader(dir / "obj.npz");
  EXPECT_EQ(reader.Read("good").AsDoubles(),
            std::vector<double>{1.0});  // others stay readable
  const std::string message = ErrorOf([&] { reader.Read("joint2num"); });
  EXPECT_NE(message.find("obj.npz"), std::string::npos) << message;
  EXPECT_NE(message.find("joint2num.npy"), std::string::npos) << message;
  EXPECT_NE(message.find("unsupported dtype 'O'"), std::string::npos)
      << message;
  EXPECT_EQ(ErrorOf([&] { ReadNpz(dir / "obj.npz"); }), message);
  EXPECT_NE(
      ErrorOf([&] {
        ParseNpy(
            HandMadeNpy(
                "{'descr': '<c16', 'fortran_order': False, 'shape': (1,), }",
                std::string(16, '\0')),
            "c.npy");
      }).find("unsupported dtype '<c16'"),
      std::string::npos);
}

TEST(NpzErrors, MissingKeyListsMembers) {
  const std::filesystem::path path = testing::CreateTestDir() / "a.npz";
  WriteNpz(path, {{"v_template", NpyArray::FromDoubles({1, 3}, {0, 0, 0})}});
  const std::string message =
      ErrorOf([&] { NpzReader(path).Read("shapedirs"); });
  EXPECT_NE(message.find("shapedirs"), std::string::npos) << message;
  EXPECT_NE(message.find("v_template"), std::string::npos) << message;
}

TEST(NpyErrors, BadMagicAndHeader) {
  EXPECT_NE(ErrorOf([] { ParseNpy("NUMPY??", "x.npy"); }).find("not a .npy"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              ParseNpy(HandMadeNpy("{'descr': '<f8', 'shape': (1,), }",
                                   std::string(8, '\0')),
                       "x.npy");
            }).find("'fortran_order'"),
            std::string::npos);
  EXPECT_NE(
      ErrorOf([] {
        ParseNpy(
            HandMadeNpy("{'descr': '<f8', 'fortran_order': False, 'shape': (1,",
                        std::string(8, '\0')),
            "x.npy");
      }).find("malformed .npy header"),
      std::string::npos);
}

TEST(Gunzip, ReadsMakeHumanTargets) {
  const std::filesystem::path dir =
      testing::SharedDataDir() / "body/makehuman/targets/macrodetails";
  if (!std::filesystem::exists(dir))
    GTEST_SKIP() << "no MakeHuman assets at " << dir;
  const std::string text = ReadGzipFile(dir / "caucasian-male-young.target.gz");
  EXPECT_EQ(text.rfind("0 .012 .904 .062\n", 0), 0u);
  // An empty target (a valid gzip member holding no bytes).
  EXPECT_EQ(
      ReadGzipFile(
          dir / "universal-male-young-averagemuscle-averageweight.target.gz"),
      "");
  EXPECT_NE(
      ErrorOf([] { Gunzip("\x1f\x8b\x08\x00garbage", "g.gz"); }).find("g.gz"),
      std::string::npos);
}

}  // namespace
}  // namespace soma
