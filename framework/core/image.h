// A small RGB raster image with drawing primitives and a PNG writer, for
// pictures a person would rather look at than read: rendered frames with
// labelled markers, coverage histograms, training curves. No GUI library:
// lines, discs, rectangles and a built-in 5x7 pixel font (ASCII; lower case
// is drawn as upper case). PNG encoding is libpng's (Debian libpng-dev).
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace soma {

struct Rgb {
  uint8_t r = 0, g = 0, b = 0;
};

inline constexpr Rgb kWhite{255, 255, 255};
inline constexpr Rgb kBlack{0, 0, 0};
inline constexpr Rgb kGray{160, 160, 160};
inline constexpr Rgb kLightGray{225, 225, 225};

/// A categorical colour (Tableau 10) for series/segment `index`.
Rgb CategoricalColor(int index);

class Image {
 public:
  Image(int width, int height, Rgb background = kWhite);

  int width() const { return width_; }
  int height() const { return height_; }
  Rgb Get(int x, int y) const;
  /// Pixels outside the image are ignored by every drawing call.
  void Set(int x, int y, Rgb color);

  void FillRect(int x0, int y0, int x1, int y1, Rgb color);
  void DrawRect(int x0, int y0, int x1, int y1, Rgb color);
  /// A line of the given thickness (pixels) between two points.
  void DrawLine(double x0,
                double y0,
                double x1,
                double y1,
                Rgb color,
                double thickness = 1.0);
  void FillCircle(double cx, double cy, double radius, Rgb color);
  /// Text with its top-left corner at (x, y); `scale` multiplies the 5x7
  /// glyphs (6 x 8 pixels per character cell at scale 1).
  void DrawText(int x, int y, std::string_view text, Rgb color, int scale = 1);
  /// Width in pixels of `text` at `scale`.
  static int TextWidth(std::string_view text, int scale = 1);

  /// Encodes the image as PNG (8-bit RGB) with libpng; throws IoError if
  /// libpng fails.
  std::vector<uint8_t> EncodePng() const;
  /// Writes the PNG atomically (temp file + rename, WriteFileAtomic);
  /// throws IoError naming the path.
  void WritePng(const std::filesystem::path& path) const;

 private:
  int width_, height_;
  std::vector<uint8_t> pixels_;  // row-major RGB
};

}  // namespace soma
