// The run's records: stats.csv (one row per frame, or per rank and update,
// as the pipeline counts them) and summary.json (the distributed pipeline's
// closing report).
#include <filesystem>
#include <memory>
#include <optional>

#include "core/io_util.hpp"
#include "outputs/outputs.hpp"
#include "host/run_loop.hpp"

namespace pp5::outputs {

namespace {

namespace fs = std::filesystem;

class StatsSink final : public host::Sink {
public:
  explicit StatsSink(const host::RunJob& j) : j_(j) {}
  void start(const host::RunStart& r) override {
    csv_.emplace((fs::path(j_.outDir) / "stats.csv").string(), r.statsColumns);
  }
  void stats(const std::vector<double>& row) override {
    if (csv_) csv_->row(row);
  }
  void ended() override { csv_.reset(); }
  std::vector<std::string> wrote() const override { return {"stats.csv"}; }

private:
  const host::RunJob& j_;
  std::optional<host::StatsCsv> csv_;
};

class SummarySink final : public host::Sink {
public:
  explicit SummarySink(const host::RunJob& j) : j_(j) {}
  void summary(const std::string& json) override {
    io::AtomicFile f((fs::path(j_.outDir) / "summary.json").string());
    f.write(json);
    f.commit();
    wrote_ = true;
  }
  std::vector<std::string> wrote() const override {
    return wrote_ ? std::vector<std::string>{"summary.json"} : std::vector<std::string>{};
  }

private:
  const host::RunJob& j_;
  bool wrote_ = false;
};

}  // namespace

std::unique_ptr<host::Sink> makeStatsSink(const host::RunJob& job) { return std::make_unique<StatsSink>(job); }
std::unique_ptr<host::Sink> makeSummarySink(const host::RunJob& job) { return std::make_unique<SummarySink>(job); }

}  // namespace pp5::outputs
