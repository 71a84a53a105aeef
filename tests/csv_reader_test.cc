// The run directory's one CSV reader (replay/csv_reader.h) in the forms its neighbours
// need: text in memory, a header that must match (velocity CSV), blank lines only at the
// end, and header-less blank-separated columns with comment lines (TUM). Each bad input
// is an InputError naming line and column.
#include "replay/csv_reader.h"

#include <gtest/gtest.h>

#include <string>

#include "core/error.h"
#include "replay/velocity_csv.h"
#include "tests/test_support.h"

namespace tofu::replay {
namespace {

constexpr char kHeader[] = "#timestamp [ns],v_x [m/s],v_y [m/s],v_z [m/s]";

using test::InputErrorOf;

TEST(CsvReader, ReadsTextWithAByteOrderMarkCrLfAndTheEurocTimestampSpelling) {
  const std::string text = "\xEF\xBB\xBF#timestamp, v_x [m/s],v_y [m/s] ,v_z [m/s]\r\n"
                           "1000,1,2,3\r\n2000,+4,5e-1,-6\r\n\r\n";
  CsvReader reader(CsvText{text, "v.csv"}, kHeader,
                   CsvOptions{.header_must_match = true, .blank_lines_only_at_end = true});
  EXPECT_GE(reader.RowsUpperBound(), 2u);
  ASSERT_TRUE(reader.Next());
  EXPECT_EQ(reader.Integer(0), 1000);
  EXPECT_EQ(reader.Number(3), 3.0);
  ASSERT_TRUE(reader.Next());
  EXPECT_EQ(reader.line(), 3);
  EXPECT_EQ(reader.Number(1), 4.0);
  EXPECT_EQ(reader.Number(2), 0.5);
  EXPECT_FALSE(reader.Next());
}

TEST(CsvReader, AHeaderThatMustMatchNamesTheFirstWrongColumn) {
  const core::InputError e = InputErrorOf([] {
    CsvReader reader(CsvText{"#timestamp [ns],v_x [m/s],vy,v_z [m/s]\n1,0,0,0\n", "v.csv"},
                     kHeader, CsvOptions{.header_must_match = true});
  });
  EXPECT_EQ(e.location().line, 1);
  EXPECT_EQ(e.location().column, 27);
  EXPECT_CONTAINS(e.what(), "column 3 should be 'v_y [m/s]', got 'vy'");
  const core::InputError count = InputErrorOf([] {
    CsvReader reader(CsvText{"#timestamp [ns],v_x [m/s]\n", "v.csv"}, kHeader,
                     CsvOptions{.header_must_match = true});
  });
  EXPECT_CONTAINS(count.what(), "2 comma-separated columns, not 4");
}

TEST(CsvReader, ABlankLineInsideTheDataIsNamedWhenBlankLinesEndIt) {
  const std::string text = std::string(kHeader) + "\n1,0,0,0\n\n  \n2,0,0,0\n";
  CsvReader strict(CsvText{text, "v.csv"}, kHeader, CsvOptions{.blank_lines_only_at_end = true});
  ASSERT_TRUE(strict.Next());
  const core::InputError e = InputErrorOf([&] { strict.Next(); });
  EXPECT_EQ(e.location().line, 3);
  EXPECT_CONTAINS(e.what(), "line 5 has another row");
  // Without the option a blank line is skipped, as in every run file.
  CsvReader lenient(CsvText{text, "v.csv"}, kHeader);
  int rows = 0;
  while (lenient.Next()) ++rows;
  EXPECT_EQ(rows, 2);
}

TEST(CsvReader, HeaderlessBlankSeparatedColumnsWithComments) {
  const std::string text = "# t x\n\n 1.5\t2 \n# another comment\n2.5   3\r\n";
  CsvReader reader(CsvText{text, "p.tum"}, "t x per line",
                   CsvOptions{.columns = {"t [s]", "x [m]"}, .whitespace_separated = true});
  EXPECT_EQ(reader.keys(), (std::vector<std::string>{"t", "x"}));
  ASSERT_TRUE(reader.Next());
  EXPECT_EQ(reader.line(), 3);
  EXPECT_EQ(reader.Text(0), "1.5");
  EXPECT_EQ(reader.FieldColumn(1), 6);
  EXPECT_EQ(reader.Number(1), 2.0);
  ASSERT_TRUE(reader.Next());
  EXPECT_EQ(reader.Number(1), 3.0);
  EXPECT_FALSE(reader.Next());

  CsvReader short_row(CsvText{"1 2\n3\n", "p.tum"}, "t x per line",
                      CsvOptions{.columns = {"t [s]", "x [m]"}, .whitespace_separated = true});
  ASSERT_TRUE(short_row.Next());
  const core::InputError e = InputErrorOf([&] { short_row.Next(); });
  EXPECT_EQ(e.location().line, 2);
  EXPECT_CONTAINS(e.what(), "expected 2 whitespace-separated fields as in the form 't x per line'");
  EXPECT_CONTAINS(e.what(), "column 2 'x [m]' and later are missing");
}

// The velocity CSV is the reader with its options, plus strictly increasing stamps and
// finite velocities.
TEST(VelocityCsv, RejectsNonFiniteVelocitiesAndStampsThatDoNotIncrease) {
  const std::string header = std::string(kHeader) + "\n";
  const estimator::VelocitySeries series =
      ParseVelocityCsv(header + "1000,0.1,0.2,0.3\n2000,0,0,0\n\n", "v.csv");
  ASSERT_EQ(series.t_ns.size(), 2u);
  EXPECT_EQ(series.v_mps[0], Eigen::Vector3d(0.1, 0.2, 0.3));
  const core::InputError nan = InputErrorOf([&] { ParseVelocityCsv(header + "1000,0,nan,0\n", "v.csv"); });
  EXPECT_EQ(nan.location().column, 8);
  EXPECT_CONTAINS(nan.what(), "NaN and Inf are not accepted");
  const core::InputError repeated =
      InputErrorOf([&] { ParseVelocityCsv(header + "1000,0,0,0\n1000,0,0,0\n", "v.csv"); });
  EXPECT_EQ(repeated.location().line, 3);
  EXPECT_CONTAINS(repeated.what(), "not after the previous sample's 1000 ns (line 2)");
  const core::InputError empty = InputErrorOf([&] { ParseVelocityCsv(header, "v.csv"); });
  EXPECT_EQ(empty.location().line, 2);
  EXPECT_CONTAINS(empty.what(), "no samples");
}

}  // namespace
}  // namespace tofu::replay
