#include "framework/body/mesh_export.h"

#include "framework/core/error.h"
#include "framework/core/file.h"
#include "framework/testing/testing.h"

#include <gtest/gtest.h>

#include <sstream>
#include <string>
#include <vector>

namespace soma {
namespace {

void Tetrahedron(Eigen::Matrix3Xd* v, Eigen::Matrix3Xi* f) {
  v->resize(3, 4);
  *v << 0, 1, 0, 0,  //
      0, 0, 1, 0,    //
      0, 0, 0, 1;
  f->resize(3, 4);
  *f << 0, 0, 0, 1,  //
      2, 1, 3, 2,    //
      1, 3, 2, 3;
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

TEST(MeshExport, WritesPlyWithMarkerPoints) {
  Eigen::Matrix3Xd v;
  Eigen::Matrix3Xi f;
  Tetrahedron(&v, &f);
  ColoredPoints points;
  points.positions = Eigen::Matrix3Xd::Constant(3, 2, 0.5);
  points.colors = {{255, 0, 0}, {0, 0, 255}};
  const auto dir = soma::testing::CreateTestDir();
  WritePly(dir / "m.ply", v, f, points);
  const auto lines = Lines(ReadFile(dir / "m.ply"));
  ASSERT_GE(lines.size(), 16u);
  EXPECT_EQ(lines[0], "ply");
  EXPECT_EQ(lines[1], "format ascii 1.0");
  EXPECT_EQ(lines[3], "element vertex 6");
  EXPECT_EQ(lines[10], "element face 4");
  EXPECT_EQ(lines[12], "end_header");
  EXPECT_EQ(lines[14], "1.000000 0.000000 0.000000 200 200 200");
  EXPECT_EQ(lines[18], "0.500000 0.500000 0.500000 0 0 255");
  EXPECT_EQ(lines[19], "3 0 2 1");
  EXPECT_EQ(lines.size(), 23u);
}

TEST(MeshExport, WritesObjWithNormalsAndPoints) {
  Eigen::Matrix3Xd v;
  Eigen::Matrix3Xi f;
  Tetrahedron(&v, &f);
  ColoredPoints points;
  points.positions = Eigen::Matrix3Xd::Zero(3, 1);
  const auto dir = soma::testing::CreateTestDir();
  WriteObj(dir / "m.obj", v, f, Eigen::Matrix3Xd::Ones(3, 4), points);
  const auto lines = Lines(ReadFile(dir / "m.obj"));
  ASSERT_EQ(lines.size(), 1u + 4 + 4 + 4 + 1 + 1);
  EXPECT_EQ(lines[1], "v 0.000000 0.000000 0.000000");
  EXPECT_EQ(lines[5], "vn 1.000000 1.000000 1.000000");
  EXPECT_EQ(lines[9], "f 1//1 3//3 2//2");  // 1-based
  EXPECT_EQ(lines[13], "v 0.000000 0.000000 0.000000 1.0000 0.0000 0.0000");
  EXPECT_EQ(lines[14], "p 5");
  WriteObj(dir / "plain.obj", v, f);
  EXPECT_EQ(Lines(ReadFile(dir / "plain.obj"))[5], "f 1 3 2");
}

TEST(MeshExport, RejectsInconsistentInput) {
  Eigen::Matrix3Xd v;
  Eigen::Matrix3Xi f;
  Tetrahedron(&v, &f);
  const auto dir = soma::testing::CreateTestDir();
  Eigen::Matrix3Xi bad = f;
  bad(2, 3) = 4;
  EXPECT_THROW(WritePly(dir / "x.ply", v, bad), ShapeError);
  EXPECT_THROW(WriteObj(dir / "x.obj", v, f, Eigen::Matrix3Xd::Ones(3, 2)),
               ShapeError);
  ColoredPoints points;
  points.positions = Eigen::Matrix3Xd::Zero(3, 2);
  points.colors = {{1, 2, 3}};
  EXPECT_THROW(WritePly(dir / "x.ply", v, f, points), ShapeError);
  EXPECT_THROW(WritePly(dir / "x.ply", v, f, {}, std::vector<Rgb>(3)),
               ShapeError);
  EXPECT_FALSE(std::filesystem::exists(dir / "x.ply"));
  WriteFileAtomic(dir / "a_file", "not a directory");
  EXPECT_THROW(WritePly(dir / "a_file" / "x.ply", v, f), IoError);
}

}  // namespace
}  // namespace soma
