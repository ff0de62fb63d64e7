#include "framework/core/image.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/core/plot.h"
#include "framework/testing/testing.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <png.h>
#include <string>
#include <vector>

namespace soma {
namespace {

using ::testing::HasSubstr;
using ::testing::ThrowsMessage;

// Decodes `png` with libpng into 8-bit RGB (width, height, pixels).
struct Decoded {
  int width = 0, height = 0;
  std::vector<uint8_t> rgb;
};

Decoded DecodePng(const std::vector<uint8_t>& png) {
  png_image image{};
  image.version = PNG_IMAGE_VERSION;
  EXPECT_TRUE(png_image_begin_read_from_memory(&image, png.data(), png.size()))
      << image.message;
  image.format = PNG_FORMAT_RGB;
  Decoded out;
  out.width = static_cast<int>(image.width);
  out.height = static_cast<int>(image.height);
  out.rgb.resize(PNG_IMAGE_SIZE(image));
  EXPECT_TRUE(png_image_finish_read(
      &image, nullptr, out.rgb.data(), /*row_stride=*/0, nullptr))
      << image.message;
  return out;
}

TEST(Image, PngRoundTripsEveryPixel) {
  Image image(7, 3, kBlack);
  image.Set(2, 1, Rgb{10, 20, 30});
  image.Set(6, 2, Rgb{255, 128, 1});
  const std::vector<uint8_t> png = image.EncodePng();
  ASSERT_GT(png.size(), 33u);
  EXPECT_EQ(std::string(png.begin(), png.begin() + 8),
            std::string("\x89PNG\r\n\x1a\n", 8));
  const Decoded decoded = DecodePng(png);
  ASSERT_EQ(decoded.width, 7);
  ASSERT_EQ(decoded.height, 3);
  for (int y = 0; y < 3; ++y) {
    for (int x = 0; x < 7; ++x) {
      const size_t at = 3 * (static_cast<size_t>(y) * 7 + x);
      const Rgb expected = image.Get(x, y);
      EXPECT_EQ(decoded.rgb[at], expected.r) << x << "," << y;
      EXPECT_EQ(decoded.rgb[at + 1], expected.g) << x << "," << y;
      EXPECT_EQ(decoded.rgb[at + 2], expected.b) << x << "," << y;
    }
  }
  EXPECT_EQ(decoded.rgb[3 * (1 * 7 + 2) + 1], 20);
}

TEST(Image, PngOfAPlotIsCompressedAndDeterministic) {
  const Image plot = LinePlot({{"loss", {0, 1, 2, 3}, {1.0, 0.5, 0.3, 0.25}}},
                              {.title = "curve"});
  const std::vector<uint8_t> png = plot.EncodePng();
  EXPECT_LT(png.size(),
            static_cast<size_t>(plot.width()) * plot.height() * 3 / 10);
  EXPECT_EQ(png, plot.EncodePng());
  EXPECT_EQ(DecodePng(png).width, plot.width());
}

TEST(Image, WritePngIsAtomicAndNamesThePathOnError) {
  const auto dir = testing::CreateTestDir();
  Image image(4, 4);
  image.WritePng(dir / "a.png");
  EXPECT_EQ(DecodePng([&] {
              const std::string bytes = ReadFile(dir / "a.png");
              return std::vector<uint8_t>(bytes.begin(), bytes.end());
            }())
                .height,
            4);
  EXPECT_FALSE(std::filesystem::exists(TempPathFor(dir / "a.png")));
  // A directory where the file should go: the write fails, naming the path.
  std::filesystem::create_directories(dir / "taken.png");
  EXPECT_THAT([&] { image.WritePng(dir / "taken.png"); },
              ThrowsMessage<IoError>(HasSubstr("taken.png")));
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
