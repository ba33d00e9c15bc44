// HyQ on flat ground with TOWR's own gaits, timed over repeated fresh solves (the wall time of
// Solve(), median printed): hyq_flat REPEATS DISTANCE DURATION [walk|trot]. walk: towr_ros's
// default combo C0 (the overlap-walk, three or four feet on the ground); trot: TOWR's trot
// stride (Run1, diagonal pairs, no flight), the gait of the BLC's HyQ preset. Phase durations
// fixed, as towr_ros leaves them.
#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include <ifopt/ipopt_solver.h>
#include <towr/initialization/gait_generator.h>
#include <towr/nlp_formulation.h>
#include <towr/terrain/examples/height_map_examples.h>

using namespace towr;

static double solve_once(double distance, double duration, bool trot, int* iterations) {
  NlpFormulation formulation;
  formulation.terrain_ = std::make_shared<FlatGround>(0.0);
  formulation.model_ = RobotModel(RobotModel::Hyq);
  auto nominal = formulation.model_.kinematic_model_->GetNominalStanceInBase();
  formulation.initial_ee_W_ = nominal;
  for (auto& p : formulation.initial_ee_W_) p.z() = 0.0;
  formulation.initial_base_.lin.at(kPos).z() = -nominal.front().z();
  formulation.final_base_.lin.at(kPos) << distance, 0.0, -nominal.front().z();
  auto gait = GaitGenerator::MakeGaitGenerator(4);
  if (trot)
    gait->SetGaits({GaitGenerator::Stand, GaitGenerator::Run1, GaitGenerator::Run1, GaitGenerator::Run1,
                    GaitGenerator::Run1E, GaitGenerator::Stand});
  else
    gait->SetCombo(GaitGenerator::C0);
  for (int ee = 0; ee < 4; ++ee) {
    formulation.params_.ee_phase_durations_.push_back(gait->GetPhaseDurations(duration, ee));
    formulation.params_.ee_in_contact_at_start_.push_back(gait->IsInContactAtStart(ee));
  }
  ifopt::Problem nlp;
  SplineHolder solution;
  for (auto c : formulation.GetVariableSets(solution)) nlp.AddVariableSet(c);
  for (auto c : formulation.GetConstraints(solution)) nlp.AddConstraintSet(c);
  for (auto c : formulation.GetCosts()) nlp.AddCostSet(c);
  auto solver = std::make_shared<ifopt::IpoptSolver>();
  solver->SetOption("print_level", 0);
  auto t0 = std::chrono::steady_clock::now();
  solver->Solve(nlp);
  auto t1 = std::chrono::steady_clock::now();
  *iterations = nlp.GetIterationCount();
  return std::chrono::duration<double>(t1 - t0).count();
}

int main(int argc, char** argv) {
  int repeats = argc > 1 ? std::atoi(argv[1]) : 5;
  double distance = argc > 2 ? std::atof(argv[2]) : 1.0, duration = argc > 3 ? std::atof(argv[3]) : 2.0;
  std::string gait = argc > 4 ? argv[4] : "walk";
  if (gait != "walk" && gait != "trot") {
    std::cerr << "gait: '" << gait << "' (expected walk or trot)" << std::endl;
    return 2;
  }
  bool trot = gait == "trot";
  std::vector<double> times;
  int iterations = 0;
  for (int i = 0; i < repeats; ++i) times.push_back(solve_once(distance, duration, trot, &iterations));
  std::vector<double> sorted = times;
  std::sort(sorted.begin(), sorted.end());
  std::cout << "{\"case\": \"towr_hyq_flat_" << distance << "m_" << duration << "s_" << (trot ? "trot" : "walk")
            << "\", \"median_s\": "
            << sorted[sorted.size() / 2] << ", \"iterations\": " << iterations << ", \"times\": [";
  for (size_t i = 0; i < times.size(); ++i) std::cout << (i ? ", " : "") << times[i];
  std::cout << "]}" << std::endl;
}
