// End-to-end tests of `penumbra probe`: the program is run as a user would, with CSV on stdin.
#include <catch2/catch.hpp>

#include <sys/wait.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "support/cli.h"
#include "support/exact_shadow.h"
#include "support/paper_scene.h"
#include "penumbra/contour_integrator.h"

namespace fs = std::filesystem;
using namespace penumbra;

namespace {

using ::test::readFile;
using Run = ::test::Run;

// Runs `penumbra probe ARGS` with `input` on stdin; stderr goes to DIR/stderr.txt.
Run probe(const std::string& args, const std::string& input, const fs::path& dir) {
    return ::test::runPenumbra("probe " + args, dir, input);
}

fs::path makeTempDir(const std::string& name) { return ::test::makeTempDir("probe", name); }

/// probe's output on stdout: checks the header and returns each row's eight numbers (x, y, z,
/// form_factor, dF_dx, dF_dy, dF_dz, shadow_rays); a number that does not read stays NaN.
std::vector<std::array<double, 8>> readRows(const std::string& out) {
    std::istringstream lines(out);
    std::string line;
    std::getline(lines, line);
    CHECK(line == "x,y,z,form_factor,dF_dx,dF_dy,dF_dz,shadow_rays");
    std::vector<std::array<double, 8>> rows;
    while (std::getline(lines, line)) {
        std::array<double, 8> v;
        v.fill(std::nan(""));
        char comma;
        std::istringstream cells(line);
        cells >> v[0];
        for (int i = 1; i < 8; ++i) cells >> comma >> v[i];
        rows.push_back(v);
    }
    return rows;
}

const char* kScene = R"({
  "lights": [{"name": "key", "corner": [-1,-1,4], "edge_u": [0,2,0], "edge_v": [2,0,0],
              "radiance": [1,1,1]}],
  "obstacles": [{"type": "sphere", "center": [0.3,0.2,2.0], "radius": 0.7, "analytic": true}],
  "receivers": [{"type": "plane", "point": [0,0,0], "normal": [0,0,1]}]
})";

}  // namespace

TEST_CASE("probe answers sensor points in order with the estimator's values", "[cli][probe]") {
    const fs::path dir = makeTempDir("ok");
    std::ofstream(dir / "scene.json") << kScene;
    const std::string input = "x,y,z,nx,ny,nz\n-2.0,0.3,0,0,0,1\n1.2,0.43,0,0,0,2\n0.6,0.4,0,0,0,1\n";
    const Run run = probe((dir / "scene.json").string(), input, dir);
    INFO(readFile(dir / "stderr.txt"));
    REQUIRE(run.exitCode == 0);
    const std::vector<std::array<double, 8>> rows = readRows(run.out);

    const RectLight light = penumbra::test::paperLight();
    Occluder occ({AnalyticSphere{Vec3(0.3, 0.2, 2.0), 0.7}});
    Occluder::Query query = occ.makeQuery();
    const std::vector<Vec3> points = {Vec3(-2.0, 0.3, 0), Vec3(1.2, 0.43, 0), Vec3(0.6, 0.4, 0)};
    REQUIRE(rows.size() == points.size());
    for (size_t k = 0; k < points.size(); ++k) {
        const Vec3& p = points[k];
        const std::array<double, 8>& v = rows[k];
        const Estimate e = contourIntegral({p, Vec3(0, 0, 1)}, light, query, AciSettings{});
        CHECK(v[0] == Approx(p.x));
        CHECK(v[3] == Approx(e.formFactor).epsilon(1e-9));
        CHECK(v[4] == Approx(e.gradient.x).margin(1e-9));
        CHECK(v[7] == e.counts.shadowRays());
        // And against the exact shadow, within the estimator's bound (see [aci] tests).
        const double exactF = exact::sphereShadowFormFactor(p, Vec3(0, 0, 1), light.corner,
                                                            light.edgeU, light.edgeV,
                                                            Vec3(0.3, 0.2, 2.0), 0.7);
        CHECK(std::abs(v[3] - exactF) < 0.0625 * unoccludedFormFactor(light, {p, Vec3(0, 0, 1)}));
    }
}

TEST_CASE("probe refuses bad input with one line, exit code 2 and no output", "[cli][probe]") {
    const fs::path dir = makeTempDir("bad");
    std::ofstream(dir / "scene.json") << kScene;
    const std::string scene = (dir / "scene.json").string();

    Run run = probe(scene, "x,y,z,nx,ny,nz\n0,0,0,0,0,1\n1,2,abc,0,0,1\n", dir);
    CHECK(run.exitCode == 2);
    CHECK(run.out.empty());
    std::string err = readFile(dir / "stderr.txt");
    CHECK(err.find("line 3, column z") != std::string::npos);
    CHECK(std::count(err.begin(), err.end(), '\n') == 1);

    run = probe(scene, "0,0,0,0,0,0\n", dir);
    CHECK(run.exitCode == 2);
    CHECK(run.out.empty());
    CHECK(readFile(dir / "stderr.txt").find("normal is zero") != std::string::npos);

    run = probe(scene + " --light fill", "0,0,0,0,0,1\n", dir);
    CHECK(run.exitCode == 2);
    CHECK(run.out.empty());

    run = probe(scene + " --aci-steps 99", "0,0,0,0,0,1\n", dir);
    CHECK(run.exitCode == 2);
    CHECK(run.out.empty());

    std::ofstream(dir / "broken.json") << R"({"lights": [{"corner": [0,0,1], "edge_u": [1,0,0], "edge_v": [2,0,0]}]})";
    run = probe((dir / "broken.json").string(), "0,0,0,0,0,1\n", dir);
    CHECK(run.exitCode == 2);
    CHECK(run.out.empty());
    err = readFile(dir / "stderr.txt");
    CHECK(err.find("broken.json") != std::string::npos);
    CHECK(err.find("/lights/0") != std::string::npos);
}

TEST_CASE("probe runs the Monte Carlo methods: values, zero gradients, rays", "[cli][probe][mc]") {
    const fs::path dir = makeTempDir("mc");
    std::ofstream(dir / "scene.json") << kScene;
    const std::string scene = (dir / "scene.json").string();
    const std::string input =
        "x,y,z,nx,ny,nz\n1.2,0.43,0,0,0,1\n0.6,0.4,0,0,0,1\n-2.0,0.3,0,0,0,1\n";
    const RectLight light = penumbra::test::paperLight();
    const std::vector<Vec3> points = {Vec3(1.2, 0.43, 0), Vec3(0.6, 0.4, 0), Vec3(-2.0, 0.3, 0)};
    for (const char* method : {"reference", "mc-adaptive", "mc-solid-angle", "mc-ratio"}) {
        INFO(method);
        const std::string samples =
            std::string(method) == "mc-adaptive" ? "" : " --samples 256";
        const Run run =
            probe(scene + " --method " + method + samples + " --seed 3", input, dir);
        INFO(readFile(dir / "stderr.txt"));
        REQUIRE(run.exitCode == 0);
        const std::vector<std::array<double, 8>> rows = readRows(run.out);
        REQUIRE(rows.size() == points.size());
        for (size_t i = 0; i < points.size(); ++i) {
            const std::array<double, 8>& v = rows[i];
            CHECK(v[4] == 0.0);
            CHECK(v[5] == 0.0);
            CHECK(v[6] == 0.0);
            const Receiver r{points[i], Vec3(0, 0, 1)};
            const double exactF =
                exact::sphereShadowFormFactor(points[i], Vec3(0, 0, 1), light.corner, light.edgeU,
                                              light.edgeV, Vec3(0.3, 0.2, 2.0), 0.7);
            if (std::string(method) == "mc-adaptive") {
                const double f0 = unoccludedFormFactor(light, r);
                // 4 rays when they agree, more where an edge crosses; biased (see [mc]), so only
                // a loose check here.
                CHECK(v[7] >= 4);
                CHECK(std::abs(v[3] - exactF) <= 0.5 * f0);
            } else {
                CHECK(v[7] == 256);
                // 5 x the independent-sample bound max / (2 sqrt N): each sample's value lies
                // in [0, max], with max the largest cos^2 A / (pi r^2) over the light for area
                // sampling, S / pi for solid-angle sampling (the larger of the two here).
                double top = 0.0;
                for (int a = 0; a <= 32; ++a) {
                    for (int b = 0; b <= 32; ++b) {
                        const Vec3 q = light.point(a / 32.0, b / 32.0) - points[i];
                        const double q2 = glm::dot(q, q);
                        top = std::max(top, q.z * q.z * light.area() / (kPi * q2 * q2));
                    }
                }
                double solidAngle = 0.0;  // two triangles, Van Oosterom and Strackee
                const std::vector<Vec3> c = light.polygon();
                for (int t = 1; t <= 2; ++t) {
                    const Vec3 a = c[0] - points[i], b = c[t] - points[i], d = c[t + 1] - points[i];
                    const double la = glm::length(a), lb = glm::length(b), ld = glm::length(d);
                    solidAngle += 2.0 * std::atan2(std::abs(glm::dot(a, glm::cross(b, d))),
                                                   la * lb * ld + glm::dot(a, b) * ld +
                                                       glm::dot(a, d) * lb + glm::dot(b, d) * la);
                }
                top = 1.01 * std::max(top, solidAngle / kPi);
                CHECK(std::abs(v[3] - exactF) <= 5.0 * top / (2.0 * 16.0));
            }
        }
    }
    // --samples is for the Monte Carlo methods only.
    const Run bad = probe(scene + " --samples 16", input, dir);
    CHECK(bad.exitCode == 2);
    CHECK(bad.out.empty());
}

TEST_CASE("probe --aci-mode picks the estimator's variant; an unknown mode is refused",
          "[cli][probe]") {
    const fs::path dir = makeTempDir("mode");
    std::ofstream(dir / "scene.json") << kScene;
    const std::string scene = (dir / "scene.json").string();
    const std::string input = "x,y,z,nx,ny,nz\n1.2,0.43,0,0,0,1\n0.6,0.4,0,0,0,1\n";

    const RectLight light = penumbra::test::paperLight();
    Occluder occ({AnalyticSphere{Vec3(0.3, 0.2, 2.0), 0.7}});
    Occluder::Query query = occ.makeQuery();
    const std::vector<Vec3> points = {Vec3(1.2, 0.43, 0), Vec3(0.6, 0.4, 0)};
    AciSettings paper;
    applyAciMode(paper, AciMode::Paper);
    // As probe does: rays start 1.5 voxels off the surface (a hair off it without voxels).
    paper.rayOffset = occ.minVoxelSize() > 0 ? 1.5 * occ.minVoxelSize() : 1e-9;

    const Run run = probe(scene + " --aci-mode paper", input, dir);
    INFO(readFile(dir / "stderr.txt"));
    REQUIRE(run.exitCode == 0);
    const std::vector<std::array<double, 8>> rows = readRows(run.out);
    REQUIRE(rows.size() == points.size());
    for (size_t k = 0; k < points.size(); ++k) {
        const Vec3& p = points[k];
        const std::array<double, 8>& v = rows[k];
        const Estimate e = contourIntegral({p, Vec3(0, 0, 1)}, light, query, paper);
        CHECK(v[3] == Approx(e.formFactor).epsilon(1e-9));
        CHECK(v[4] == Approx(e.gradient.x).margin(1e-9));
        CHECK(v[5] == Approx(e.gradient.y).margin(1e-9));
        CHECK(v[7] == e.counts.shadowRays());
    }

    const Run bad = probe(scene + " --aci-mode bogus", input, dir);
    CHECK(bad.exitCode == 2);
    CHECK(bad.out.empty());
    const std::string err = readFile(dir / "stderr.txt");
    CHECK(err.find("--aci-mode") != std::string::npos);
    CHECK(err.find("bogus") != std::string::npos);
    CHECK(std::count(err.begin(), err.end(), '\n') == 1);
}

TEST_CASE("probe --light all adds the lights; --columns per-light shows each", "[cli][probe][lights]") {
    const fs::path dir = makeTempDir("all");
    std::ofstream(dir / "scene.json") << R"({
      "lights": [{"name": "key", "corner": [-1,-1,4], "edge_u": [0,2,0], "edge_v": [2,0,0]},
                 {"name": "hex", "type": "polygon", "radiance": [0.2, 0.3, 1],
                  "vertices": [[2,0,3],[1,-0.8,3],[0,0,3],[0.5,0.9,3],[1.5,0.9,3]]},
                 {"name": "round", "type": "disc", "center": [-1.5,0.5,3], "normal": [0,0,-1],
                  "radius": 0.5}],
      "obstacles": [{"type": "sphere", "center": [0.3,0.2,2.0], "radius": 0.7, "analytic": true}]
    })";
    const std::string input = "x,y,z,nx,ny,nz\n-2.0,0.3,0,0,0,1\n1.2,0.43,0,0,0,2\n0.6,0.4,0,0.3,0,1\n";
    const std::string scene = (dir / "scene.json").string();
    std::vector<std::vector<std::array<double, 8>>> single;
    for (const char* name : {"key", "hex", "round"}) {
        const Run run = probe(scene + " --light " + name, input, dir);
        REQUIRE(run.exitCode == 0);
        single.push_back(readRows(run.out));
    }
    const Run all = probe(scene + " --light all", input, dir);
    REQUIRE(all.exitCode == 0);
    const std::vector<std::array<double, 8>> sum = readRows(all.out);
    REQUIRE(sum.size() == 3);
    for (size_t k = 0; k < sum.size(); ++k) {
        // The CSV carries 12 significant digits: the sum matches to that.
        CHECK(sum[k][3] == Approx(single[0][k][3] + single[1][k][3] + single[2][k][3]).epsilon(1e-10));
        CHECK(sum[k][4] == Approx(single[0][k][4] + single[1][k][4] + single[2][k][4]).epsilon(1e-9).margin(1e-12));
        CHECK(sum[k][7] == single[0][k][7] + single[1][k][7] + single[2][k][7]);
    }
    const Run columns = probe(scene + " --light all --columns per-light", input, dir);
    REQUIRE(columns.exitCode == 0);
    std::istringstream lines(columns.out);
    std::string line;
    std::getline(lines, line);
    CHECK(line == "x,y,z,form_factor,dF_dx,dF_dy,dF_dz,shadow_rays,form_factor:key,"
                  "form_factor:hex,form_factor:round");
    for (size_t k = 0; k < 3; ++k) {
        REQUIRE(std::getline(lines, line));
        std::vector<double> v;
        std::istringstream cells(line);
        for (std::string cell; std::getline(cells, cell, ',');) v.push_back(std::stod(cell));
        REQUIRE(v.size() == 11);
        for (size_t l = 0; l < 3; ++l) CHECK(v[8 + l] == Approx(single[l][k][3]).epsilon(1e-10));
    }
    const Run bad = probe(scene + " --light key --columns per-light", input, dir);
    CHECK(bad.exitCode == 2);
    CHECK(bad.out.empty());
}
