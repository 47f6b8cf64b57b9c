// Malformed and inconsistent files: each one throws DatasetError naming the file, the line and
// a reason — never a crash, never a silently wrong dataset.
#include <gtest/gtest.h>

#include <filesystem>

#include "io_test_util.h"
#include "solvers/io/dataset_reader.h"

namespace loopd::io {
namespace {

// Small well-formed pieces to build broken files from.
const std::string V0 = "VERTEX_SE2 0 0 0 0\n";
const std::string V1 = "VERTEX_SE2 1 1 0 0\n";
const std::string E01 = "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n";
const std::string kInfo6 = " 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1";
const std::string Q0 = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n";
const std::string Q1 = "VERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n";
const std::string QE01 = "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1" + kInfo6 + "\n";

// Reads `content` from a scratch file and checks the error's file, line, reason and message.
void expectError(const std::string& content, int line, const std::string& reason,
                 const std::string& suffix = ".g2o") {
  const test::ScratchFile file(content, suffix);
  try {
    readDataset(file.path());
    ADD_FAILURE() << "no error for:\n" << content;
  } catch (const DatasetError& e) {
    EXPECT_EQ(e.file(), file.path());
    EXPECT_EQ(e.line(), line) << e.what();
    EXPECT_NE(e.reason().find(reason), std::string::npos)
        << "reason: " << e.reason() << "\nwanted: " << reason;
    const std::string where = line > 0 ? file.path() + ":" + std::to_string(line) : file.path();
    EXPECT_EQ(std::string(e.what()), where + ": " + e.reason());
  }
}

TEST(Malformed, MessageNamesFileLineAndReason) {
  const test::ScratchFile file(V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 0 0 1\n", ".g2o");
  try {
    readDataset(file.path());
    FAIL();
  } catch (const DatasetError& e) {
    EXPECT_EQ(std::string(e.what()),
              file.path() + ":3: EDGE_SE2 expects 11 numbers after the tag, found 9");
  }
}

TEST(Malformed, NotFinite) {
  expectError(V0 + "VERTEX_SE2 1 nan 0 0\n" + E01, 2, "VERTEX_SE2 field 3 'nan' is not finite");
  expectError(V0 + V1 + "EDGE_SE2 0 1 NaN 0 0 1 0 0 1 0 1\n", 3, "field 4 'NaN' is not finite");
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 inf 0 0 1 0 1\n", 3, "field 7 'inf' is not finite");
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 -inf\n", 3, "'-inf' is not finite");
  expectError(E01 + "EDGE_SE2 1 2 1e400 0 0 1 0 0 1 0 1\n", 2, "'1e400' is out of range");
  expectError("ODOMETRY 0 1 1 0 0 1 0 0 1 0 nan\n", 1, "'nan' is not finite", ".txt");
}

TEST(Malformed, WrongFieldCount) {
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 0 0 1\n", 3,
              "EDGE_SE2 expects 11 numbers after the tag, found 9");
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1 7\n", 3,
              "EDGE_SE2 expects 11 numbers after the tag, found 12");
  expectError(V0 + "VERTEX_SE2 1 0 0\n" + E01, 2,
              "VERTEX_SE2 expects 4 numbers after the tag, found 3");
  expectError(Q0 + Q1 + "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0 0\n", 3,
              "EDGE_SE3:QUAT expects 30 numbers after the tag, found 12");
  expectError("VERTEX2 0 0 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0\n", 2,
              "EDGE2 expects 11 numbers after the tag, found 10", ".graph");
  expectError("EQUIV 1\n", 1, "EQUIV expects 2 numbers after the tag, found 1", ".graph");
  expectError("LANDMARK 0 1 1 1 1 0\n", 1, "LANDMARK expects 7 numbers after the tag, found 6",
              ".txt");
  expectError(V0 + "FIX\n", 2, "FIX expects at least 1 number after the tag, found 0");
}

TEST(Malformed, TrailingGarbage) {
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1 garbage\n", 3, "found 12");
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1x\n", 3,
              "EDGE_SE2 field 12 '1x' is not a number");
}

TEST(Malformed, NotANumber) {
  expectError(V0 + "VERTEX_SE2 1 abc 0 0\n" + E01, 2, "VERTEX_SE2 field 3 'abc' is not a number");
  expectError(V0 + "VERTEX_SE2 1.5 0 0 0\n" + E01, 2, "field 2 '1.5' is not an integer id");
  expectError(V0 + "VERTEX_SE2 x1 0 0 0\n" + E01, 2, "field 2 'x1' is not an integer id");
  expectError(V0 + "VERTEX_SE2 99999999999999999999 0 0 0\n", 2, "out of range for an id");
  // A key holds 40 bits of an id: 2^40 would be pose 0 again, −1 pose 2^40 − 1.
  expectError(V0 + "VERTEX_SE2 1099511627776 0 0 0\n" + E01, 2,
              "VERTEX_SE2 field 2 '1099511627776' is out of range for an id (0 to 1099511627775)");
  expectError(V0 + "VERTEX_SE2 -1 0 0 0\n" + E01, 2, "'-1' is out of range for an id");
  expectError(V0 + V1 + "EDGE_SE2 0 1099511627777 1 0 0 1 0 0 1 0 1\n", 3,
              "out of range for an id");
  EXPECT_EQ(parseG2o(V0 + "VERTEX_SE2 1099511627775 0 0 0\nEDGE_SE2 0 1099511627775 1 0 0 1 0 0 "
                          "1 0 1\n",
                     "top.g2o")
                .poses[1]
                .id,
            1099511627775);
  expectError(V0 + "VERTEX_SE2 1 0x10 0 0\n", 2, "'0x10' is not a number");
  // A huge garbage token is quoted short.
  const test::ScratchFile file(V0 + "VERTEX_SE2 1 " + std::string(100000, 'z') + " 0 0\n", ".g2o");
  try {
    readDataset(file.path());
    FAIL();
  } catch (const DatasetError& e) {
    EXPECT_LT(e.reason().size(), 120u) << e.reason();
    EXPECT_NE(e.reason().find("is not a number"), std::string::npos);
  }
}

TEST(Malformed, InformationNotPositiveDefinite) {
  const std::string why = "EDGE_SE2 information matrix is not positive definite";
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n", 3, why);  // negative
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 0 0 0 0 0 0\n", 3, why);   // zero
  expectError(V0 + V1 + "EDGE_SE2 0 1 1 0 0 1 2 0 1 0 1\n", 3, why);   // indefinite
  expectError(
      Q0 + Q1 + "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 0\n", 3,
      "EDGE_SE3:QUAT information matrix is not positive definite");
  expectError(E01 + "EDGE_SE2_XY 1 5 1 1 1 0 -1\n", 2,
              "EDGE_SE2_XY information matrix is not positive definite");
  // TORO's order: the fourth value is I33.
  expectError("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 1 0 1 0 0 0\n", 3,
              "EDGE2 information matrix is not positive definite", ".graph");
}

TEST(Malformed, CovarianceNotPositiveDefinite) {
  expectError("ODOMETRY 0 1 1 0 0 1 0 0 1 0 -1\n", 1,
              "ODOMETRY covariance matrix is not positive definite", ".txt");
  expectError("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK 0 3 1 1 1 2 1\n", 2,
              "LANDMARK covariance matrix is not positive definite", ".txt");
}

TEST(Malformed, ZeroQuaternion) {
  expectError(Q0 + "VERTEX_SE3:QUAT 1 1 0 0 0 0 0 0\n" + QE01, 2,
              "VERTEX_SE3:QUAT quaternion has zero norm");
  expectError(Q0 + Q1 + "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 0" + kInfo6 + "\n", 3,
              "EDGE_SE3:QUAT quaternion has zero norm");
}

TEST(Malformed, UnknownTag) {
  expectError(V0 + "VERTEX_SE4 1 0 0 0\n", 2, "unknown g2o tag 'VERTEX_SE4'");
  expectError(V0 + "EDGE2 0 1 1 0 0 1 0 1 1 0 0\n", 2, "unknown g2o tag 'EDGE2'");
  expectError("# header\n\nHELLO world\n", 3, "unknown tag 'HELLO'");
  expectError(std::string("\x01\x02\x03\n", 4), 1, "unknown tag");
  expectError("VERTEX2 0 0 0 0\nVERTEX_SE2 1 0 0 0\n", 2, "unknown TORO tag 'VERTEX_SE2'",
              ".graph");
  expectError("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nVERTEX_SE2 1 0 0 0\n", 2,
              "unknown Victoria Park tag 'VERTEX_SE2'", ".txt");
}

TEST(Malformed, MissingVertex) {
  expectError(V0 + V1 + "EDGE_SE2 0 5 1 0 0 1 0 0 1 0 1\n", 3,
              "edge 0 -> 5: pose 5 is not defined by any vertex line");
  expectError(V0 + V1 + E01 + "EDGE_SE2_XY 1 9 1 1 1 0 1\n", 4, "landmark 9 is not defined");
  expectError("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\nEQUIV 0 9\n", 4,
              "pose 9 is not defined", ".graph");
}

TEST(Malformed, VertexOfTheWrongKind) {
  expectError(V0 + "VERTEX_XY 1 1 1\n" + E01, 3,
              "vertex 1 (line 2) is a landmark, but is used as a pose");
  expectError(V0 + V1 + "EDGE_SE2_XY 0 1 1 1 1 0 1\n", 3,
              "vertex 1 (line 2) is a pose, but is used as a landmark");
  // Without vertices, g2o ids still name one variable each.
  expectError(E01 + "EDGE_SE2_XY 1 0 1 1 1 0 1\n", 2,
              "id 0 is used both as a pose and as a landmark");
}

TEST(Malformed, DuplicateVertex) {
  expectError(V0 + V1 + "VERTEX_SE2 0 2 2 2\n" + E01, 3, "vertex 0 is already defined on line 1");
  expectError(V0 + "VERTEX_XY 0 1 1\n", 2, "vertex 0 is already defined on line 1");
}

TEST(Malformed, SelfLoop) {
  expectError(V0 + V1 + "EDGE_SE2 1 1 1 0 0 1 0 0 1 0 1\n", 3,
              "EDGE_SE2 connects vertex 1 to itself");
  expectError("EQUIV 4 4\n", 1, "EQUIV joins vertex 4 to itself", ".graph");
}

TEST(Malformed, Mixed2DAnd3D) {
  expectError(V0 + Q1, 2, "VERTEX_SE3:QUAT is 3D but line 1 made this a 2D file");
  expectError(Q0 + Q1 + QE01 + E01, 4, "EDGE_SE2 is 2D but line 1 made this a 3D file");
  expectError(E01 + "EDGE_SE3_TRACKXYZ 1 5 1 1 1 1 0 0 1 0 1\n", 2, "is 3D but line 1");
}

TEST(Malformed, NoEdges) {
  expectError("", 0, "no edges");
  expectError("# only a comment\n\n   \n", 0, "no edges");
  expectError(V0 + V1, 0, "the file has no edges");
}

TEST(Malformed, UnreadableFile) {
  const std::string missing = test::datasetPath("no-such-file.g2o");
  try {
    readDataset(missing);
    FAIL();
  } catch (const DatasetError& e) {
    EXPECT_EQ(e.line(), 0);
    EXPECT_EQ(e.file(), missing);
    EXPECT_EQ(std::string(e.what()), missing + ": No such file or directory");
  }
  try {
    readDataset(std::filesystem::temp_directory_path().string());
    FAIL();
  } catch (const DatasetError& e) {
    EXPECT_EQ(e.line(), 0);
    EXPECT_EQ(e.reason(), "Is a directory");
  }
}

TEST(Malformed, UnreachablePose) {
  expectError(E01 + "EDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\n", 2,
              "pose 2 is not connected to pose 0 by between edges");
  // A pose seen only through a landmark is not reachable either.
  expectError("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK 7 3 1 1 1 0 1\n", 2,
              "pose 7 is not connected to pose 0", ".txt");
}

TEST(WellFormed, VerticesMayFollowEdges) {
  const Dataset ds = parseG2o(V0 + E01 + V1, "late.g2o");
  EXPECT_TRUE(ds.hadVertices);
  EXPECT_EQ(ds.poses.size(), 2u);
  EXPECT_EQ(ds.poses[1].line, 3);
}

TEST(WellFormed, VictoriaLandmarkMayShareAnIdWithAPose) {
  const Dataset ds =
      parseVictoria("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK 1 1 2 0 1 0 1\n", "ids.txt");
  ASSERT_EQ(ds.landmarks.size(), 1u);
  EXPECT_EQ(ds.landmarks[0].id, 1);
  EXPECT_NEAR(ds.landmarks[0].value[0], 3.0, 1e-15);
}

TEST(WellFormed, AByteOrderMarkIsNotPartOfTheFirstTag) {
  const Dataset ds = parseDataset("\xEF\xBB\xBF" + V0 + V1 + E01, "bom.g2o");
  EXPECT_EQ(ds.format, "g2o");
  EXPECT_EQ(ds.poses.size(), 2u);
  EXPECT_EQ(ds.poses[0].line, 1);
}

TEST(WellFormed, FixLinesAreAccepted) {
  const Dataset ds = parseG2o(V0 + V1 + "FIX 0\n" + E01, "fix.g2o");
  EXPECT_EQ(ds.edges.size(), 1u);
}

TEST(WellFormed, QuaternionsAreNormalised) {
  const Dataset ds = parseG2o(
      "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 2\nVERTEX_SE3:QUAT 1 0 0 0 0 0 3 4\n"
      "EDGE_SE3:QUAT 0 1 0 0 0 0 0 0.6 0.8" +
          kInfo6 + "\n",
      "quat.g2o");
  EXPECT_EQ(ds.poses[0].value[6], 1.0);
  EXPECT_DOUBLE_EQ(ds.poses[1].value[5], 0.6);
  EXPECT_DOUBLE_EQ(ds.poses[1].value[6], 0.8);
}

}  // namespace
}  // namespace loopd::io
