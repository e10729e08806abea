// Drift model (paper eq. 1): spec parsing, the smoothing derivative and the
// fits against numpy (tools/reference/drift_reference.py, data in
// tests/analysis/data/drift_*), exact recovery, block-size invariance, errors.
// Tolerances are stated at each comparison.
#include "gyrotherm/analysis/drift_model.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace gyrotherm::analysis {
namespace {

const std::string kDataDir = std::string(GYROTHERM_TEST_DATA_DIR) + "/analysis/data/";
const char* const kRegenerate =
    " (regenerate with /usr/bin/python3 tools/reference/drift_reference.py)";

// ---- spec parsing ----------------------------------------------------------

TEST(DriftModelSpec, ParsesGoodSpecs) {
  struct Case {
    const char* text;
    int t, r, g;
    const char* canonical;
  };
  const Case cases[] = {
      {"T1", 1, 0, 0, "T1"},
      {"T4+R1+G1", 4, 1, 1, "T4+R1+G1"},
      {"G1+T4+R1", 4, 1, 1, "T4+R1+G1"},
      {"R2", 0, 2, 0, "R2"},
      {"T0+G3", 0, 0, 3, "G3"},
      {" T2 + G1 ", 2, 0, 1, "T2+G1"},
      {"T4+R4+G4", 4, 4, 4, "T4+R4+G4"},
  };
  for (const Case& c : cases) {
    auto spec = parse_model_spec(c.text);
    ASSERT_TRUE(spec.ok()) << c.text << ": " << spec.error().message;
    EXPECT_EQ(spec->t_order, c.t) << c.text;
    EXPECT_EQ(spec->r_order, c.r) << c.text;
    EXPECT_EQ(spec->g_order, c.g) << c.text;
    EXPECT_EQ(to_string(*spec), c.canonical) << c.text;
    auto again = parse_model_spec(to_string(*spec));
    ASSERT_TRUE(again.ok());
    EXPECT_EQ(*again, *spec);
  }
}

TEST(DriftModelSpec, RejectsBadSpecsNamingThePart) {
  struct Case {
    const char* text;
    const char* message_part;
  };
  const Case cases[] = {
      {"", "empty"},
      {"   ", "empty"},
      {"T5", "T5: order must be 0..4"},
      {"T4+X1", "X1: unknown term (T, R, G)"},
      {"T1+T2", "T2: term T given more than once"},
      {"T1++G1", "empty term"},
      {"T1+", "empty term"},
      {"T", "T: order must be 0..4"},
      {"T12", "T12: order must be 0..4"},
      {"t1", "t1: unknown term"},
      {"G-1", "G-1: order must be 0..4"},
      {"T0", "no term of order >= 1"},
      {"T0+R0", "no term of order >= 1"},
  };
  for (const Case& c : cases) {
    auto spec = parse_model_spec(c.text);
    ASSERT_FALSE(spec.ok()) << "\"" << c.text << "\" parsed";
    EXPECT_NE(spec.error().message.find(c.message_part), std::string::npos)
        << "\"" << c.text << "\": " << spec.error().message;
  }
}

// ---- reference data --------------------------------------------------------

struct ReferenceSeries {
  AnalysisSeries series;
  std::vector<double> derivative;
  double derivative_window_s = 0;
};

ReferenceSeries load_series() {
  const std::string path = kDataDir + "drift_series.txt";
  std::ifstream in(path);
  EXPECT_TRUE(in) << "cannot open " << path << kRegenerate;
  ReferenceSeries r;
  std::string line, key;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    ls >> key;
    if (key == "derivative_window_s") {
      ls >> r.derivative_window_s;
    } else if (key == "point") {
      std::string v[5];
      ls >> v[0] >> v[1] >> v[2] >> v[3] >> v[4];
      r.series.t_s.push_back(std::stod(v[0]));
      r.series.rate_dph.push_back(std::stod(v[1]));
      r.series.top_c.push_back(std::stod(v[2]));
      r.series.side_c.push_back(std::stod(v[3]));
      r.derivative.push_back(std::stod(v[4]));
    }
  }
  return r;
}

struct ReferenceFit {
  std::map<std::string, std::string> scalars;
  std::map<std::string, std::pair<double, double>> coefs;  // value, std error
  std::vector<std::pair<std::size_t, double>> fitted;
  double num(const std::string& k) const { return std::stod(scalars.at(k)); }
};

ReferenceFit load_fit(const std::string& name) {
  const std::string path = kDataDir + "drift_fit_" + name + ".txt";
  std::ifstream in(path);
  EXPECT_TRUE(in) << "cannot open " << path << kRegenerate;
  ReferenceFit f;
  std::string line, key;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    ls >> key;
    if (key == "coef") {
      std::string n, b, s;
      ls >> n >> b >> s;
      f.coefs[n] = {std::stod(b), std::stod(s)};
    } else if (key == "fitted") {
      std::string i, v;
      ls >> i >> v;
      f.fitted.emplace_back(std::stoul(i), std::stod(v));
    } else {
      ls >> f.scalars[key];
    }
  }
  return f;
}

double max_abs(const std::vector<double>& v) {
  double m = 0;
  for (double x : v) m = std::max(m, std::abs(x));
  return m;
}

// The derivative over all 5000 points, ends included, to 1e-9 of its largest value.
TEST(DriftDerivativeReference, MatchesNumpy) {
  const ReferenceSeries r = load_series();
  ASSERT_EQ(r.series.t_s.size(), 5000u);
  std::vector<double> shell(r.series.t_s.size());
  for (std::size_t i = 0; i < shell.size(); ++i) {
    shell[i] = (r.series.top_c[i] + r.series.side_c[i]) / 2;
  }
  const std::vector<double> d = smoothing_derivative(r.series.t_s, shell, r.derivative_window_s);
  ASSERT_EQ(d.size(), r.derivative.size());
  const double scale = max_abs(r.derivative);
  for (std::size_t i = 0; i < d.size(); ++i) {
    ASSERT_NEAR(d[i], r.derivative[i], 1e-9 * scale) << "point " << i;
  }
}

TEST(DriftModel, SmoothingDerivativeOfALineIsExactAndShrinksAtTheEdges) {
  std::vector<double> t, y;
  for (int i = 0; i < 50; ++i) {
    t.push_back(1e5 + 0.5 * i);
    y.push_back(3.0 - 0.25 * t.back());
  }
  for (double d : smoothing_derivative(t, y, 10.0)) EXPECT_NEAR(d, -0.25, 1e-12);
  // A window narrower than the spacing still uses the two neighbours.
  for (double d : smoothing_derivative(t, y, 0.1)) EXPECT_NEAR(d, -0.25, 1e-12);
  // y = t^2: a centred window gives 2 t exactly; at the first point the window
  // is cut to [t0, t0 + 5] and the slope is that of the right half.
  std::vector<double> tq, yq;
  for (int i = 0; i <= 20; ++i) {
    tq.push_back(i);
    yq.push_back(static_cast<double>(i) * i);
  }
  const std::vector<double> dq = smoothing_derivative(tq, yq, 10.0);
  EXPECT_NEAR(dq[10], 20.0, 1e-12);
  EXPECT_NEAR(dq[0], 5.0, 1e-12);    // slope of i^2 over i = 0..5
  EXPECT_NEAR(dq[20], 35.0, 1e-12);  // over i = 15..20
}

struct FitCase {
  const char* name;
  double coef_rel;  // tolerance on coefficients and standard errors
};

std::ostream& operator<<(std::ostream& os, const FitCase& c) { return os << c.name; }

class DriftModelReference : public ::testing::TestWithParam<FitCase> {};

// Fitted values to 1e-9 relative (of the largest |y|), the scalars to 1e-9;
// coefficients and standard errors to coef_rel relative: 1e-9 where the design
// is well conditioned, looser where the raw powers of T make the physical
// coefficients themselves ill conditioned (numpy's values then carry the same
// error).
TEST_P(DriftModelReference, MatchesNumpy) {
  static const ReferenceSeries r = load_series();
  const ReferenceFit ref = load_fit(GetParam().name);
  ASSERT_FALSE(ref.scalars.empty());
  auto spec = parse_model_spec(ref.scalars.at("spec"));
  ASSERT_TRUE(spec.ok());
  auto form = parse_drift_model_form(ref.scalars.at("form"));
  ASSERT_TRUE(form.ok());
  DriftFitOptions options;
  options.derivative_window_s = r.derivative_window_s;
  auto fit = fit_drift_model(r.series, *spec, *form, options);
  ASSERT_TRUE(fit.ok()) << fit.error().message;

  EXPECT_EQ(fit->n, static_cast<std::size_t>(ref.num("n")));
  EXPECT_EQ(fit->parameters, static_cast<std::size_t>(ref.num("p")));
  EXPECT_NEAR(fit->l0_dph, ref.num("l0_dph"), 1e-12 * std::abs(ref.num("l0_dph")));
  EXPECT_NEAR(fit->residual_std_dph, ref.num("residual_std_dph"),
              1e-9 * ref.num("residual_std_dph"));
  EXPECT_NEAR(fit->r_squared, ref.num("r_squared"), 1e-9);

  ASSERT_EQ(fit->coefficients.size(), ref.coefs.size());
  const double rel = GetParam().coef_rel;
  for (const auto& [name, value_se] : ref.coefs) {
    ASSERT_TRUE(fit->coefficients.count(name)) << name;
    EXPECT_NEAR(fit->coefficients.at(name), value_se.first, rel * std::abs(value_se.first)) << name;
    EXPECT_NEAR(fit->std_errors.at(name), value_se.second, rel * value_se.second) << name;
  }

  auto predicted = predict_drift(*fit, r.series);
  ASSERT_TRUE(predicted.ok()) << predicted.error().message;
  const double scale = max_abs(r.series.rate_dph);
  ASSERT_GT(ref.fitted.size(), 1000u);
  for (const auto& [i, value] : ref.fitted) {
    ASSERT_NEAR((*predicted)[i], value, 1e-9 * scale) << "point " << i;
  }
}

INSTANTIATE_TEST_SUITE_P(Fits, DriftModelReference,
                         ::testing::Values(FitCase{"t1_paper", 1e-9}, FitCase{"t2g1_paper", 1e-9},
                                           FitCase{"t4_paper", 1e-9}, FitCase{"t4r1g1_paper", 1e-9},
                                           FitCase{"t4r1g1_centered", 1e-9},
                                           FitCase{"t2r2g2_centered", 1e-9}),
                         [](const auto& info) { return std::string(info.param.name); });

// ---- synthetic checks ------------------------------------------------------

// A sweep over 1 Hz points: T from -20 to 60 °C with a wiggle so dT/dt varies,
// a gradient that is not a function of T.
AnalysisSeries sweep(std::size_t n) {
  AnalysisSeries s;
  for (std::size_t k = 0; k < n; ++k) {
    const double x = static_cast<double>(k) / static_cast<double>(n);
    const double temp = -20.0 + 80.0 * x + 2.0 * std::sin(40.0 * x);
    const double grad = 0.5 + std::cos(7.0 * x);
    s.t_s.push_back(250.0 + static_cast<double>(k));
    s.top_c.push_back(temp + grad / 2);
    s.side_c.push_back(temp - grad / 2);
    s.rate_dph.push_back(0.0);
  }
  return s;
}

std::vector<double> shell_temperature(const AnalysisSeries& s) {
  std::vector<double> t(s.t_s.size());
  for (std::size_t i = 0; i < t.size(); ++i) t[i] = (s.top_c[i] + s.side_c[i]) / 2;
  return t;
}

// Noiseless L = c + sum A_i T^i + B_1 dT/dt + C_1 dT: the centred form must
// give back every coefficient (1e-9 relative) and a zero residual.
TEST(DriftModel, RecoversANoiselessPolynomial) {
  AnalysisSeries s = sweep(3000);
  const std::vector<double> temp = shell_temperature(s);
  const std::vector<double> rate = smoothing_derivative(s.t_s, temp, 60.0);
  const std::map<std::string, double> truth = {
      {"intercept", 7.9}, {"T1", 0.02}, {"T2", -4e-4}, {"T3", 5e-6},
      {"T4", -3e-8},      {"R1", 25.0}, {"G1", 0.15},
  };
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    const double t = temp[i];
    s.rate_dph[i] = truth.at("intercept") + truth.at("T1") * t + truth.at("T2") * t * t +
                    truth.at("T3") * t * t * t + truth.at("T4") * t * t * t * t +
                    truth.at("R1") * rate[i] + truth.at("G1") * (s.top_c[i] - s.side_c[i]);
  }
  auto fit = fit_drift_model(s, *parse_model_spec("T4+R1+G1"), DriftModelForm::kCentered);
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  for (const auto& [name, value] : truth) {
    EXPECT_NEAR(fit->coefficients.at(name), value, 1e-9 * std::abs(value)) << name;
  }
  EXPECT_LT(fit->residual_std_dph, 1e-10);
  EXPECT_NEAR(fit->r_squared, 1.0, 1e-12);
  auto predicted = predict_drift(*fit, s);
  ASSERT_TRUE(predicted.ok());
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    ASSERT_NEAR((*predicted)[i], s.rate_dph[i], 1e-9 * max_abs(s.rate_dph)) << i;
  }
}

// Two runs with their own L0 (different offsets) fitted together in the paper
// form recover the shared coefficients exactly; each run's L0 is its own; a
// pooled fit equals the fit of the concatenation when the offsets are equal
// and the derivative never crosses runs; drift_terms is the model without L0.
TEST(DriftModel, SeveralRunsKeepTheirOwnL0AndShareTheCoefficients) {
  AnalysisSeries a = sweep(2000);
  AnalysisSeries b = sweep(2500);
  for (double& t : b.top_c) t += 7.5;  // a warmer run, shifted in time too
  for (double& t : b.side_c) t += 7.3;
  for (double& t : b.t_s) t += 1e5;
  const auto fill = [](AnalysisSeries& s, double offset) {
    const std::vector<double> temp = shell_temperature(s);
    const std::vector<double> rate = smoothing_derivative(s.t_s, temp, 60.0);
    for (std::size_t i = 0; i < s.t_s.size(); ++i) {
      s.rate_dph[i] = offset + 0.02 * temp[i] - 3e-4 * temp[i] * temp[i] + 30.0 * rate[i] +
                      0.2 * (s.top_c[i] - s.side_c[i]);
    }
  };
  fill(a, 7.9);
  fill(b, 9.4);
  const std::vector<AnalysisSeries> runs = {a, b};
  auto fit = fit_drift_model(runs, *parse_model_spec("T2+R1+G1"), DriftModelForm::kPaper);
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  ASSERT_EQ(fit->l0_per_series_dph.size(), 2u);
  for (std::size_t r = 0; r < 2; ++r) {
    double sum = 0;
    std::size_t count = 0;
    for (std::size_t i = 0; runs[r].t_s[i] - runs[r].t_s[0] < 120.0; ++i, ++count) {
      sum += runs[r].rate_dph[i];
    }
    EXPECT_NEAR(fit->l0_per_series_dph[r], sum / static_cast<double>(count), 1e-12) << r;
  }
  EXPECT_EQ(fit->n, a.t_s.size() + b.t_s.size());
  // y = L - L0 has an offset the paper form cannot absorb exactly (no
  // intercept), so compare against the fit's own residual instead: a second
  // fit with the offsets swapped must give different L0 but the terms differ
  // only through that offset.
  auto terms_a = drift_terms(*fit, a);
  ASSERT_TRUE(terms_a.ok()) << terms_a.error().message;
  auto predicted_a = predict_drift(*fit, a);
  ASSERT_TRUE(predicted_a.ok());
  for (std::size_t i = 0; i < a.t_s.size(); ++i) {
    ASSERT_NEAR((*predicted_a)[i] - (*terms_a)[i], fit->l0_dph, 1e-9) << i;
  }
  double direct = 0;
  const std::vector<double> temp_b = shell_temperature(b);
  const std::vector<double> rate_b = smoothing_derivative(b.t_s, temp_b, 60.0);
  auto terms_b = drift_terms(*fit, b);
  ASSERT_TRUE(terms_b.ok());
  for (std::size_t i = 0; i < b.t_s.size(); i += 97) {
    direct = fit->coefficients.at("T1") * temp_b[i] +
             fit->coefficients.at("T2") * temp_b[i] * temp_b[i] +
             fit->coefficients.at("R1") * rate_b[i] +
             fit->coefficients.at("G1") * (b.top_c[i] - b.side_c[i]);
    ASSERT_NEAR((*terms_b)[i], direct, 1e-9 * std::max(1.0, std::abs(direct))) << i;
  }

  // Centred form: the offsets differ by run, the intercept is shared, so the
  // pooled centred fit of two runs with equal offsets recovers the truth.
  fill(b, 7.9);
  const std::vector<AnalysisSeries> same = {a, b};
  auto centred = fit_drift_model(same, *parse_model_spec("T2+R1+G1"), DriftModelForm::kCentered);
  ASSERT_TRUE(centred.ok()) << centred.error().message;
  EXPECT_NEAR(centred->coefficients.at("intercept"), 7.9, 1e-9 * 7.9);
  EXPECT_NEAR(centred->coefficients.at("T1"), 0.02, 1e-9 * 0.02);
  EXPECT_NEAR(centred->coefficients.at("T2"), -3e-4, 1e-9 * 3e-4);
  EXPECT_NEAR(centred->coefficients.at("R1"), 30.0, 1e-9 * 30.0);
  EXPECT_NEAR(centred->coefficients.at("G1"), 0.2, 1e-9 * 0.2);
  auto centred_terms = drift_terms(*centred, b);
  ASSERT_TRUE(centred_terms.ok());
  for (std::size_t i = 0; i < b.t_s.size(); i += 101) {
    EXPECT_NEAR(b.rate_dph[i] - (*centred_terms)[i], 7.9, 1e-8) << i;
  }

  // A bad second series is named.
  AnalysisSeries bad = b;
  bad.rate_dph[3] = std::nan("");
  const std::vector<AnalysisSeries> with_bad = {a, bad};
  auto err = fit_drift_model(with_bad, *parse_model_spec("T2"), DriftModelForm::kPaper);
  ASSERT_FALSE(err.ok());
  EXPECT_NE(err.error().message.find("series 2"), std::string::npos) << err.error().message;
  EXPECT_NE(err.error().message.find("rate_dph[3]"), std::string::npos) << err.error().message;
  EXPECT_FALSE(fit_drift_model(std::span<const AnalysisSeries>(), *parse_model_spec("T1"),
                               DriftModelForm::kPaper)
                   .ok());
}

// The same fit with blocks of 7, 64 and 4096 rows agrees to 1e-12: fitted
// values, standard errors and residual std relative, the scaled coefficients
// normwise (relative to the largest; single coefficients of nearly collinear
// powers move by cond x eps relative to the vector, not to themselves). Only
// the (p + 1) x (p + 1) factor is carried from block to block.
TEST(DriftModel, BlockSizeDoesNotChangeTheAnswer) {
  static const ReferenceSeries r = load_series();
  const double y_scale = max_abs(r.series.rate_dph);
  for (const char* spec_text : {"T2+G1", "T4+R1+G1"}) {
    for (DriftModelForm form : {DriftModelForm::kPaper, DriftModelForm::kCentered}) {
      std::vector<DriftFit> fits;
      std::vector<std::vector<double>> predicted;
      for (std::size_t block : {7u, 64u, 4096u}) {
        DriftFitOptions options;
        options.block_rows = block;
        auto fit = fit_drift_model(r.series, *parse_model_spec(spec_text), form, options);
        ASSERT_TRUE(fit.ok()) << fit.error().message;
        fits.push_back(*fit);
        auto pred = predict_drift(*fit, r.series);
        ASSERT_TRUE(pred.ok());
        predicted.push_back(*pred);
      }
      const double beta_scale = max_abs(fits[0].scaled_coefficients);
      for (std::size_t k = 1; k < fits.size(); ++k) {
        SCOPED_TRACE(std::string(spec_text) + " " + std::string(to_string(form)) + " block #" +
                     std::to_string(k));
        for (std::size_t c = 0; c < fits[0].scaled_coefficients.size(); ++c) {
          EXPECT_NEAR(fits[k].scaled_coefficients[c], fits[0].scaled_coefficients[c],
                      1e-12 * beta_scale)
              << c;
        }
        for (const auto& [name, se] : fits[0].std_errors) {
          EXPECT_NEAR(fits[k].std_errors.at(name), se, 1e-12 * se) << name;
        }
        EXPECT_NEAR(fits[k].residual_std_dph, fits[0].residual_std_dph,
                    1e-12 * fits[0].residual_std_dph);
        EXPECT_NEAR(fits[k].r_squared, fits[0].r_squared, 1e-12);
        for (std::size_t i = 0; i < predicted[0].size(); ++i) {
          ASSERT_NEAR(predicted[k][i], predicted[0][i], 1e-12 * y_scale) << i;
        }
      }
    }
  }
}

// ---- solver paths ----------------------------------------------------------

// The Gram path (well-conditioned scaled design) and the Householder path
// agree: fitted values and R^2 to 1e-12, residual std (y'y - |Q'y|^2 in the
// Gram path) to 1e-10 relative, standard
// errors to 1e-10, coefficients to 1e-10 of the largest.
TEST(DriftModel, GramPathAgreesWithHouseholder) {
  static const ReferenceSeries r = load_series();
  const double y_scale = max_abs(r.series.rate_dph);
  for (const char* spec_text : {"T2+G1", "T4+R1+G1", "T2+R2+G2"}) {
    for (DriftModelForm form : {DriftModelForm::kPaper, DriftModelForm::kCentered}) {
      SCOPED_TRACE(std::string(spec_text) + " " + std::string(to_string(form)));
      DriftFitOptions fast;
      fast.derivative_window_s = r.derivative_window_s;
      DriftFitOptions slow = fast;
      slow.force_householder = true;
      auto a = fit_drift_model(r.series, *parse_model_spec(spec_text), form, fast);
      auto b = fit_drift_model(r.series, *parse_model_spec(spec_text), form, slow);
      ASSERT_TRUE(a.ok() && b.ok());
      EXPECT_EQ(b->solver, "householder");
      if (form == DriftModelForm::kCentered) {
        EXPECT_EQ(a->solver, "gram");
      }
      EXPECT_NEAR(a->residual_std_dph, b->residual_std_dph, 1e-10 * b->residual_std_dph);
      EXPECT_NEAR(a->r_squared, b->r_squared, 1e-12);
      EXPECT_NEAR(a->condition_estimate, b->condition_estimate, 1e-8 * b->condition_estimate);
      const double beta_scale = max_abs(b->scaled_coefficients);
      for (std::size_t c = 0; c < b->scaled_coefficients.size(); ++c) {
        EXPECT_NEAR(a->scaled_coefficients[c], b->scaled_coefficients[c], 1e-10 * beta_scale) << c;
      }
      for (const auto& [name, se] : b->std_errors) {
        EXPECT_NEAR(a->std_errors.at(name), se, 1e-10 * se) << name;
      }
      auto pa = predict_drift(*a, r.series);
      auto pb = predict_drift(*b, r.series);
      ASSERT_TRUE(pa.ok() && pb.ok());
      for (std::size_t i = 0; i < pa->size(); ++i) {
        ASSERT_NEAR((*pa)[i], (*pb)[i], 1e-12 * y_scale) << i;
      }
    }
  }
}

// A series long enough to be split over two threads (the halves meet in the
// middle of a derivative window): the Gram path still agrees with the
// single-threaded Householder path.
TEST(DriftModel, LongSeriesSplitOverThreadsAgrees) {
  AnalysisSeries s = sweep(300000);
  const std::vector<double> temp = shell_temperature(s);
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    s.rate_dph[i] = 7.9 + 0.02 * temp[i] + 0.2 * (s.top_c[i] - s.side_c[i]) +
                    0.05 * std::sin(1.3 * static_cast<double>(i) * static_cast<double>(i % 17));
  }
  DriftFitOptions slow;
  slow.force_householder = true;
  const DriftModelSpec spec = *parse_model_spec("T2+R1+G1");
  auto a = fit_drift_model(s, spec, DriftModelForm::kCentered);
  auto b = fit_drift_model(s, spec, DriftModelForm::kCentered, slow);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->solver, "gram");
  EXPECT_NEAR(a->residual_std_dph, b->residual_std_dph, 1e-10 * b->residual_std_dph);
  // T2 and R1 are ~0 in truth: coefficients normwise, standard errors each.
  const double beta_scale = max_abs(b->scaled_coefficients);
  for (std::size_t c = 0; c < b->scaled_coefficients.size(); ++c) {
    EXPECT_NEAR(a->scaled_coefficients[c], b->scaled_coefficients[c], 1e-10 * beta_scale) << c;
  }
  for (const auto& [name, se] : b->std_errors) {
    EXPECT_NEAR(a->std_errors.at(name), se, 1e-9 * se) << name;
  }
}

// The Gram matrix is accumulated in provisional variables centred and scaled
// from a strided sample, then mapped to the documented ones. Here every
// sampled point (i % 10 == 0 at this length) carries an offset in T, so the
// sample's centre of T is off: by ~0.2 std (mapped) and by ~3 std (the Gram
// matrix is accumulated again). Both give the documented scaling (mean and
// population std of T) and the Householder answer.
TEST(DriftModel, GramFromAnOffSampleStillGivesTheDocumentedFit) {
  for (double offset_c : {5.0, 300.0}) {
    SCOPED_TRACE(offset_c);
    AnalysisSeries s = sweep(40960);
    for (std::size_t i = 0; i < s.t_s.size(); i += 10) {
      s.top_c[i] += offset_c;
      s.side_c[i] += offset_c;
    }
    const std::vector<double> temp = shell_temperature(s);
    double mean = 0, var = 0;
    for (double t : temp) mean += t;
    mean /= static_cast<double>(temp.size());
    for (double t : temp) var += (t - mean) * (t - mean);
    const double std_c = std::sqrt(var / static_cast<double>(temp.size()));
    for (std::size_t i = 0; i < s.t_s.size(); ++i) {
      s.rate_dph[i] = 7.9 + 0.02 * temp[i] - 1e-4 * temp[i] * temp[i] +
                      0.2 * (s.top_c[i] - s.side_c[i]) +
                      0.05 * std::sin(1.3 * static_cast<double>(i) * static_cast<double>(i % 17));
    }
    DriftFitOptions slow;
    slow.force_householder = true;
    const DriftModelSpec spec = *parse_model_spec("T2+G1");
    auto a = fit_drift_model(s, spec, DriftModelForm::kCentered);
    auto b = fit_drift_model(s, spec, DriftModelForm::kCentered, slow);
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_EQ(a->solver, "gram");
    EXPECT_NEAR(a->t_center, mean, 1e-12 * std_c);
    EXPECT_NEAR(a->t_scale, std_c, 1e-12 * std_c);
    EXPECT_EQ(a->t_center, b->t_center);
    EXPECT_EQ(a->t_scale, b->t_scale);
    EXPECT_NEAR(a->residual_std_dph, b->residual_std_dph, 1e-10 * b->residual_std_dph);
    const double beta_scale = max_abs(b->scaled_coefficients);
    for (std::size_t c = 0; c < b->scaled_coefficients.size(); ++c) {
      EXPECT_NEAR(a->scaled_coefficients[c], b->scaled_coefficients[c], 1e-10 * beta_scale) << c;
    }
    for (const auto& [name, se] : b->std_errors) {
      EXPECT_NEAR(a->std_errors.at(name), se, 1e-10 * se) << name;
    }
  }
}

// An ill-conditioned scaled design (paper form, raw powers of T / max|T| with
// T far from 0) is solved by Householder, not by the Gram matrix.
TEST(DriftModel, IllConditionedDesignFallsBackToHouseholder) {
  AnalysisSeries s = sweep(3000);
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    s.top_c[i] += 60.0;  // T in 40 .. 120 degC: z = T / max in 0.3 .. 1
    s.side_c[i] += 60.0;
    s.rate_dph[i] = 1.0 + 0.001 * s.top_c[i] + 0.01 * std::sin(0.1 * static_cast<double>(i));
  }
  auto fit = fit_drift_model(s, *parse_model_spec("T4"), DriftModelForm::kPaper);
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  EXPECT_GT(fit->condition_estimate, 100.0);
  EXPECT_EQ(fit->solver, "householder");
}

// A near-exact fit makes y'y - |Q'y|^2 meaningless; the Gram path then takes
// RSS from the residuals (one refinement pass) and agrees with Householder.
TEST(DriftModel, CloseFitRefinesTheGramResidual) {
  AnalysisSeries s = sweep(3000);
  const std::vector<double> temp = shell_temperature(s);
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    s.rate_dph[i] = 7.9 + 0.02 * temp[i] - 4e-4 * temp[i] * temp[i] +
                    1e-9 * std::sin(0.37 * static_cast<double>(i));
  }
  DriftFitOptions slow;
  slow.force_householder = true;
  auto a = fit_drift_model(s, *parse_model_spec("T2"), DriftModelForm::kCentered);
  auto b = fit_drift_model(s, *parse_model_spec("T2"), DriftModelForm::kCentered, slow);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->solver, "gram+refined");
  EXPECT_NEAR(a->residual_std_dph, b->residual_std_dph, 1e-6 * b->residual_std_dph);
  EXPECT_GT(a->residual_std_dph, 1e-10);  // the 1e-9 wiggle, not rounding noise
  for (const auto& [name, value] : b->coefficients) {
    EXPECT_NEAR(a->coefficients.at(name), value, 1e-10 * std::abs(value)) << name;
  }
}

// ---- errors ----------------------------------------------------------------

TEST(DriftModel, ConstantTemperatureIsAnErrorNamingT) {
  AnalysisSeries s = sweep(500);
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    s.top_c[i] = 25.5;
    s.side_c[i] = 24.5;
    s.rate_dph[i] = 8.0 + 0.001 * static_cast<double>(i % 7);
  }
  for (DriftModelForm form : {DriftModelForm::kPaper, DriftModelForm::kCentered}) {
    auto fit = fit_drift_model(s, *parse_model_spec("T1"), form);
    ASSERT_FALSE(fit.ok());
    EXPECT_NE(fit.error().message.find("term T "), std::string::npos) << fit.error().message;
    // dT/dt is then zero too.
    auto fit_r = fit_drift_model(s, *parse_model_spec("R1"), form);
    ASSERT_FALSE(fit_r.ok());
    EXPECT_NE(fit_r.error().message.find("term R "), std::string::npos) << fit_r.error().message;
  }
}

TEST(DriftModel, CollinearTermsAreAnErrorNamingTheTerm) {
  AnalysisSeries s = sweep(500);
  for (std::size_t i = 0; i < s.t_s.size(); ++i) {
    const double temp = 10.0 + 0.05 * static_cast<double>(i);
    s.top_c[i] = temp * 1.05;  // top - side = 0.1 x mean shell temperature
    s.side_c[i] = temp * 0.95;
    s.rate_dph[i] = 1.0 + 0.01 * temp;
  }
  auto fit = fit_drift_model(s, *parse_model_spec("T1+G1"), DriftModelForm::kPaper);
  ASSERT_FALSE(fit.ok());
  EXPECT_NE(fit.error().message.find("rank-deficient at term G1"), std::string::npos)
      << fit.error().message;
}

TEST(DriftModel, TooFewPointsIsAnError) {
  AnalysisSeries s = sweep(7);
  auto fit = fit_drift_model(s, *parse_model_spec("T4+R1+G1"), DriftModelForm::kCentered);
  ASSERT_FALSE(fit.ok());  // 7 points, 7 parameters
  EXPECT_NE(fit.error().message.find("7 points for 7 parameters"), std::string::npos)
      << fit.error().message;
  auto empty = fit_drift_model(AnalysisSeries{}, *parse_model_spec("T1"), DriftModelForm::kPaper);
  ASSERT_FALSE(empty.ok());
}

TEST(DriftModel, NonFiniteInputIsAnErrorNamingTheIndex) {
  AnalysisSeries s = sweep(100);
  s.side_c[42] = std::nan("");
  auto fit = fit_drift_model(s, *parse_model_spec("T1"), DriftModelForm::kPaper);
  ASSERT_FALSE(fit.ok());
  EXPECT_NE(fit.error().message.find("side_c[42]"), std::string::npos) << fit.error().message;

  s = sweep(100);
  s.rate_dph[3] = INFINITY;
  fit = fit_drift_model(s, *parse_model_spec("T1"), DriftModelForm::kPaper);
  ASSERT_FALSE(fit.ok());
  EXPECT_NE(fit.error().message.find("rate_dph[3]"), std::string::npos) << fit.error().message;

  s = sweep(100);
  s.t_s[10] = s.t_s[9];
  fit = fit_drift_model(s, *parse_model_spec("T1"), DriftModelForm::kPaper);
  ASSERT_FALSE(fit.ok());
  EXPECT_NE(fit.error().message.find("t_s[10]"), std::string::npos) << fit.error().message;
}

TEST(DriftModel, InvalidOptionsAreAnError) {
  DriftFitOptions options;
  options.block_rows = 0;
  std::string why;
  EXPECT_FALSE(options.is_valid(&why));
  EXPECT_NE(why.find("block_rows"), std::string::npos);
  auto fit = fit_drift_model(sweep(100), *parse_model_spec("T1"), DriftModelForm::kPaper, options);
  EXPECT_FALSE(fit.ok());
  options = {};
  options.derivative_window_s = 0;
  EXPECT_FALSE(options.is_valid(&why));
  EXPECT_TRUE(DriftFitOptions{}.is_valid(&why));
}

}  // namespace
}  // namespace gyrotherm::analysis
