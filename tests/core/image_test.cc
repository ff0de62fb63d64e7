#include "framework/core/image.h"

#include "framework/core/file.h"
#include "framework/core/plot.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <zlib.h>

namespace soma {
namespace {

uint32_t ReadU32(const std::vector<uint8_t>& b, size_t at) {
  return (uint32_t(b[at]) << 24) | (uint32_t(b[at + 1]) << 16) |
         (uint32_t(b[at + 2]) << 8) | b[at + 3];
}

TEST(Image, PngHasSignatureSizeAndDecodablePixels) {
  Image image(7, 3, kBlack);
  image.Set(2, 1, Rgb{10, 20, 30});
  const std::vector<uint8_t> png = image.EncodePng();
  ASSERT_GT(png.size(), 33u);
  EXPECT_EQ(png[0], 0x89);
  EXPECT_EQ(png[1], 'P');
  EXPECT_EQ(ReadU32(png, 16), 7u);  // IHDR width
  EXPECT_EQ(ReadU32(png, 20), 3u);  // IHDR height
  // Inflate the IDAT chunk and check the pixel we set.
  const size_t idat = 8 + 25;  // signature + IHDR chunk
  ASSERT_EQ(std::string(png.begin() + idat + 4, png.begin() + idat + 8),
            "IDAT");
  const uint32_t length = ReadU32(png, idat);
  std::vector<uint8_t> raw(3 * (7 * 3 + 1));
  uLongf raw_size = raw.size();
  ASSERT_EQ(uncompress(raw.data(), &raw_size, png.data() + idat + 8, length),
            Z_OK);
  ASSERT_EQ(raw_size, raw.size());
  const size_t row1 = 1 * (7 * 3 + 1);
  EXPECT_EQ(raw[row1], 0);  // filter byte
  EXPECT_EQ(raw[row1 + 1 + 2 * 3], 10);
  EXPECT_EQ(raw[row1 + 1 + 2 * 3 + 1], 20);
  EXPECT_EQ(raw[row1 + 1 + 2 * 3 + 2], 30);
}

TEST(Image, TextDrawsInkInsideItsBox) {
  Image image(40, 10);
  image.DrawText(1, 1, "C7", kBlack);
  int ink = 0, outside = 0;
  for (int y = 0; y < 10; ++y) {
    for (int x = 0; x < 40; ++x) {
      const bool dark = image.Get(x, y).r == 0;
      const bool in_box =
          x >= 1 && x < 1 + Image::TextWidth("C7") && y >= 1 && y < 8;
      ink += dark && in_box;
      outside += dark && !in_box;
    }
  }
  EXPECT_GT(ink, 15);
  EXPECT_EQ(outside, 0);
}

TEST(Plot, NiceTicksCoverTheRange) {
  const std::vector<double> ticks = NiceTicks(0.0, 0.93);
  ASSERT_GE(ticks.size(), 3u);
  EXPECT_DOUBLE_EQ(ticks.front(), 0.0);
  EXPECT_LE(ticks.back(), 0.93);
  EXPECT_NEAR(ticks[1] - ticks[0], 0.2, 1e-12);
}

TEST(Plot, LinePlotWritesAPng) {
  const auto dir = testing::CreateTestDir();
  LinePlot({{"loss", {0, 1, 2, 3}, {1.0, 0.5, 0.3, 0.25}}}, {.title = "curve"})
      .WritePng(dir / "curve.png");
  EXPECT_GT(ReadFile(dir / "curve.png").size(), 100u);
}

}  // namespace
}  // namespace soma
