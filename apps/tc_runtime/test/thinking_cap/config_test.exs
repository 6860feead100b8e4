defmodule ThinkingCap.ConfigTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config
  alias ThinkingCap.Config.{ADF, RDF, WDF}

  @examples Path.expand("../../../../priv/examples", __DIR__)

  @moduletag :tmp_dir

  defp write(dir, name, text) do
    path = Path.join(dir, name)
    File.write!(path, text)
    path
  end

  # "line:column" of the first `token` on `line` of `source`: where an error
  # about that value must point
  defp at(source, line, token) do
    text = source |> String.split("\n") |> Enum.at(line - 1)
    {col, _} = :binary.match(text, token)
    "#{line}:#{col + 1}"
  end

  defp errors(path) do
    assert {:error, errors} = Config.read(path)
    Enum.map(errors, &to_string/1)
  end

  @module_ok "[module: My.Mod, activity: :periodic, period: 0.1]"

  describe "the example set" do
    test "the office ADF, RDF and WDF load with their defaults" do
      assert {:ok, %ADF{} = adf} = Config.read(Path.join(@examples, "office.adf"))
      assert adf.robot == :r1
      assert adf.rdf == Path.join(@examples, "office_robot.rdf")
      assert adf.nodes == %{main: :"tc_main@127.0.0.1", nav: :"tc_nav@127.0.0.1"}
      assert %{port: 4000, public_view: false, rosbridge_port: 9090} = adf.dashboard
      base = Enum.find(adf.modules, &(&1.name == :base))

      assert %{
               module: ThinkingCap.Sim.Robot,
               period: 0.01,
               deadline: 0.003,
               priority: 90,
               fallback: :stop
             } = base

      planner = Enum.find(adf.modules, &(&1.name == :planner))
      # deadline defaults to the period
      assert planner.deadline == 0.5

      assert %{activity: :background, node: :local} =
               Enum.find(adf.modules, &(&1.name == :logger))

      assert {:ok, %RDF{} = rdf} = Config.read(adf.rdf)
      assert rdf.kinematics.type == :differential
      assert [%{name: :sonar, count: 8, range: {0.05, 5.0}} | _] = rdf.sensors
      assert %{max_reflections: 2, rate: 10.0} = hd(rdf.sensors)

      assert {:ok, %WDF{} = wdf} = Config.read(adf.wdf)
      assert length(wdf.walls) == 10
      assert %{name: :b_door, open: false} = Enum.find(wdf.doors, &(&1.name == :b_door))
      assert %{at: {1.0, 1.0, 0.0}} = Enum.find(wdf.waypoints, &(&1.name == :dock))
      assert %{at: {3.5, 7.0}} = Enum.find(wdf.waypoints, &(&1.name == :lab_bench))
      assert wdf.grid == nil
    end

    test "an empty world is a world", %{tmp_dir: dir} do
      assert {:ok, %WDF{walls: [], doors: []}} =
               Config.read(write(dir, "empty.wdf", ~s([name: "empty"])))
    end

    test "a crowd section: its defaults, and bad values at their keys", %{tmp_dir: dir} do
      path = write(dir, "crowd.wdf", ~s([name: "c", crowd: [count: 20, seed: 3]]))

      assert {:ok, %WDF{crowd: crowd}} = Config.read(path)

      assert crowd == %{
               count: 20,
               seed: 3,
               points: 3,
               reach: 10.0,
               speed: {0.6, 1.2},
               radius: 0.25
             }

      assert {:ok, %WDF{crowd: nil}} = Config.read(write(dir, "none.wdf", ~s([name: "n"])))

      bad = write(dir, "bad.wdf", ~s([name: "c", crowd: [count: -1, points: 1, speed: {1, 0}]]))
      errors = Enum.join(errors(bad), "\n")
      assert errors =~ "crowd.count"
      assert errors =~ "crowd.points"
      assert errors =~ "crowd.speed"
    end
  end

  describe "never evaluated" do
    test "a call is refused at its position and not run", %{tmp_dir: dir} do
      sentinel = write(dir, "sentinel", "still here")

      source = """
      [
        robot: File.rm!(#{inspect(sentinel)}),
        modules: []
      ]
      """

      path = write(dir, "evil.adf", source)
      assert [error] = errors(path)

      assert error =~
               "evil.adf:#{at(source, 2, "File")}: expected a literal value, got the expression File.rm!("

      assert File.exists?(sentinel)
    end

    test "variables, interpolation, attributes, functions and operators are refused", %{
      tmp_dir: dir
    } do
      path =
        write(dir, "code.wdf", """
        [
          name: "x\#{1 + 1}",
          walls: [{{a, 0}, {1, 1}}],
          rooms: @rooms,
          doors: &IO.puts/1,
          beacons: 1 + 2
        ]
        """)

      assert [interp, var, attr, fun, op] = errors(path)
      assert interp =~ "code.wdf:2:9: string interpolation"
      assert var =~ "code.wdf:3:13: variables are not allowed (found a)"
      assert attr =~ "code.wdf:4:10: module attributes are not allowed"
      assert fun =~ "code.wdf:5:10: functions are not allowed"
      assert op =~ "code.wdf:6:14: expected a literal value"
    end

    test "a syntax error names its place", %{tmp_dir: dir} do
      assert [error] =
               errors(write(dir, "broken.rdf", "[\n  name: \"r\",\n  footprint: [radius: ]\n]\n"))

      assert error =~ ~r/^.*broken\.rdf:3:\d+: syntax error/
    end
  end

  describe "schema errors" do
    test "an unknown key says where, and what was meant", %{tmp_dir: dir} do
      path =
        write(dir, "typo.adf", """
        [
          robot: :r1,
          modules: [
            base: [module: My.Mod, activity: :periodic, perod: 0.1]
          ]
        ]
        """)

      assert [unknown, missing] = errors(path)
      assert unknown =~ "typo.adf:4:49: unknown key :perod in modules.base; did you mean :period?"
      assert missing =~ "typo.adf:4:11: modules.base: a periodic module needs period: seconds"
    end

    test "a wrong type says what was expected and what was found", %{tmp_dir: dir} do
      source = """
      [
        name: "r",
        footprint: [radius: -0.2],
        kinematics: [type: :hovercraft],
        sensors: [[name: "laser", type: :laser, range: {8, 1}, fov: 3.14, beams: 0]]
      ]
      """

      path = write(dir, "types.rdf", source)

      assert errors(path) == [
               "#{path}:#{at(source, 3, "-0.2")}: footprint.radius: expected a positive number, got -0.2",
               "#{path}:#{at(source, 4, ":hover")}: kinematics.type: expected one of :differential, :tricycle, :ackermann, got :hovercraft",
               "#{path}:#{at(source, 5, "\"laser")}: sensors[0].name: expected an atom like :name, got \"laser\"",
               "#{path}:#{at(source, 5, "{8")}: sensors[0].range: expected a range {min, max} with 0 <= min < max, got {8, 1}",
               "#{path}:#{at(source, 5, "0]]")}: sensors[0].beams: expected a positive integer, got 0"
             ]
    end

    test "missing required keys and every error of a file are reported at once", %{tmp_dir: dir} do
      assert [robot, modules] = errors(write(dir, "bare.adf", "[nodes: []]"))
      assert robot =~ "bare.adf:1:1: the file: missing required key :robot"
      assert modules =~ "missing required key :modules"
    end

    test "a file that is not a keyword list", %{tmp_dir: dir} do
      assert [error] = errors(write(dir, "list.wdf", "[1, 2]"))

      assert error =~
               "list.wdf:1:1: the file: expected a keyword list like [key: value, ...], got [1, 2]"
    end

    test "a key given twice", %{tmp_dir: dir} do
      assert [error] = errors(write(dir, "twice.wdf", ~s([name: "a",\n name: "b"])))
      assert error =~ "twice.wdf:2:2: key :name given twice in the file"
    end
  end

  describe "the ADF's record: section" do
    test "is off by default, filled with defaults when given, and checked", %{tmp_dir: dir} do
      assert {:ok, adf} = Config.read(write(dir, "plain.adf", "[robot: :r1, modules: []]"))
      assert %{enabled: false, dir: "recordings", compression: :zstd} = adf.record

      on = """
      [robot: :r1, record: [enabled: true, dir: "runs", compression: :lz4,
        templates: [{:laser, :r1, :_}]], modules: []]
      """

      assert {:ok, adf} = Config.read(write(dir, "on.adf", on))

      assert %{
               enabled: true,
               dir: "runs",
               compression: :lz4,
               chunk_bytes: 1_048_576,
               chunk_seconds: 1.0,
               file_seconds: 600.0,
               templates: [{:laser, :r1, :_}]
             } = adf.record

      bad = """
      [robot: :r1, record: [enabled: true, compresion: :lz4, chunk_seconds: 0], modules: []]
      """

      assert [unknown, seconds] = errors(write(dir, "bad.adf", bad))
      assert unknown =~ "unknown key :compresion in record; did you mean :compression?"
      assert seconds =~ "record.chunk_seconds: expected a number from 0.01 to 60, got 0"
    end
  end

  describe "the ADF's black_box: section" do
    test "is filled with defaults, its switch left unset, and checked", %{tmp_dir: dir} do
      assert {:ok, adf} = Config.read(write(dir, "plain.adf", "[robot: :r1, modules: []]"))

      assert %{enabled: nil, seconds: 60.0, after: 5.0, dir: "black_box", misses: 5} =
               adf.black_box

      on = "[robot: :r1, black_box: [enabled: true, seconds: 10, after: 0], modules: []]"
      assert {:ok, adf} = Config.read(write(dir, "on.adf", on))
      assert %{enabled: true, seconds: 10.0, after: +0.0, max_messages: 500_000} = adf.black_box

      bad = "[robot: :r1, black_box: [seconds: 0, afer: 1], modules: []]"
      assert [unknown, seconds] = errors(write(dir, "bad.adf", bad))
      assert unknown =~ "unknown key :afer in black_box; did you mean :after?"
      assert seconds =~ "black_box.seconds: expected a number from 1 to 3600, got 0"
    end
  end

  describe "ADF checks across keys" do
    test "nodes that are not declared, timing that cannot hold, referenced files that are missing",
         %{tmp_dir: dir} do
      source = """
      [
        robot: :r1,
        rdf: "missing.rdf",
        nodes: [main: :"a@127.0.0.1", bad: :nohost],
        modules: [
          a: [module: My.A, node: :nav, activity: :periodic, period: 0.1, deadline: 0.2],
          b: [module: My.B, activity: :event, period: 1, standby: [:ghost]],
          c: [module: :not_a_module, activity: :background, subscribe: [[:scan]]]
        ]
      ]
      """

      path = write(dir, "cross.adf", source)

      assert errors(path) == [
               "#{path}:#{at(source, 8, ":not_a")}: modules.c.module: expected a module name like ThinkingCap.Sim.Robot, got :not_a_module",
               "#{path}:#{at(source, 8, "[:scan]")}: modules.c.subscribe[0]: expected a blackboard template (a tuple), got [:scan]",
               "#{path}:#{at(source, 4, ":nohost")}: nodes.bad: expected a node name like :\"name@host\", got :nohost",
               "#{path}:#{at(source, 6, ":nav")}: modules.a.node: node :nav is not declared in nodes (declared: :main, :bad)",
               "#{path}:#{at(source, 6, "0.2]")}: modules.a.deadline: 0.2 s is longer than the period 0.1 s",
               "#{path}:#{at(source, 7, ":ghost")}: modules.b.standby[0]: node :ghost is not declared in nodes (declared: :main, :bad)",
               "#{path}:#{at(source, 7, "1,")}: modules.b.period: only periodic modules have a period (this one is event)",
               "#{path}:#{at(source, 3, "\"missing")}: rdf: no such file #{Path.join(dir, "missing.rdf")}"
             ]
    end

    test "a lead too long, one that runs past the period, one on an event module", %{tmp_dir: dir} do
      source = """
      [
        robot: :r1,
        modules: [
          a: [module: My.A, activity: :periodic, period: 0.01, deadline: 0.008, lead: 0.003],
          b: [module: My.B, activity: :event, lead: 0.001],
          c: [module: My.C, activity: :periodic, period: 0.1, deadline: 0.095, lead: 0.005],
          d: [module: My.D, activity: :periodic, period: 0.1, deadline: 0.05, lead: 0.03]
        ]
      ]
      """

      path = write(dir, "lead.adf", source)

      assert errors(path) == [
               "#{path}:#{at(source, 7, "0.03]")}: modules.d.lead: expected a number from 0.0 to 0.005, got 0.03",
               "#{path}:#{at(source, 4, "0.003]")}: modules.a.lead: 0.003 s early with a deadline of 0.008 s runs past the period 0.01 s (deadline + lead <= period)",
               "#{path}:#{at(source, 5, "0.001]")}: modules.b.lead: only periodic modules have a lead (this one is event)"
             ]
    end

    test "with no nodes declared, :local is the only node", %{tmp_dir: dir} do
      path =
        write(
          dir,
          "solo.adf",
          "[robot: :r1, modules: [a: [module: My.A, node: :main, activity: :background]]]"
        )

      assert [error] = errors(path)
      assert error =~ "node :main is not declared in nodes (no nodes are declared, so use :local)"
      ok = write(dir, "solo_ok.adf", "[robot: :r1, modules: [a: #{@module_ok}]]")
      assert {:ok, %ADF{modules: [%{node: :local, deadline: 0.1}]}} = Config.read(ok)
    end
  end

  describe "RDF and WDF checks across keys" do
    test "drives need their geometry; sensors their parameters and unique names", %{tmp_dir: dir} do
      path =
        write(dir, "drive.rdf", """
        [
          name: "r",
          footprint: [radius: 0.2, polygon: [{0, 0}, {1, 0}, {0, 1}]],
          kinematics: [type: :ackermann, wheelbase: 1.2],
          sensors: [[name: :s, type: :sonar, range: {0.1, 5}], [name: :s, type: :bumper]]
        ]
        """)

      assert errors(path) == [
               "#{path}:3:14: footprint: give radius or polygon, not both",
               "#{path}:4:15: kinematics: a ackermann drive needs track: (m between the steered wheels (ackermann: required))",
               "#{path}:4:15: kinematics: a ackermann drive needs max_steering: (rad (tricycle, ackermann: required))",
               "#{path}:5:13: sensors[0]: a sonar sensor needs fov:",
               "#{path}:5:63: sensors[1].name: :s is used by another sensor"
             ]
    end

    test "docking: is optional; given, it is filled with defaults and checked", %{tmp_dir: dir} do
      base =
        ~s(name: "r", footprint: [radius: 0.2], kinematics: [type: :tricycle, wheelbase: 1.0, max_steering: 1.0])

      assert {:ok, %RDF{docking: nil}} = Config.read(write(dir, "plain.rdf", "[#{base}]"))

      assert {:ok, %RDF{docking: docking}} =
               Config.read(write(dir, "dock.rdf", "[#{base}, docking: [direction: :reverse]]"))

      assert docking == %{
               position_tolerance: 0.1,
               heading_tolerance: 0.1,
               direction: :reverse,
               approach: 1.5,
               speed: 0.2
             }

      path = write(dir, "bad.rdf", "[#{base}, docking: [direction: :sideways, speed: 0]]")
      assert [direction, speed] = errors(path)
      assert direction =~ "docking.direction: expected one of :forward, :reverse, got :sideways"
      assert speed =~ "docking.speed: expected a positive number, got 0"
    end

    test "a sensor's link: needs a urdf:; crosstalk: is a boolean", %{tmp_dir: dir} do
      source = """
      [
        name: "r",
        footprint: [radius: 0.2],
        kinematics: [type: :differential, wheel_radius: 0.03, wheel_separation: 0.2],
        sensors: [
          [name: :sonar, type: :sonar, range: {0.1, 5}, fov: 0.3, crosstalk: :yes],
          [name: :laser, type: :laser, range: {0.1, 5}, fov: 3, beams: 9, link: "base_scan"],
          [name: :bump, type: :bumper, link: :base_link]
        ]
      ]
      """

      path = write(dir, "link.rdf", source)

      assert errors(path) == [
               "#{path}:#{at(source, 6, ":yes")}: sensors[0].crosstalk: expected true or false, got :yes",
               "#{path}:#{at(source, 8, ":base_link")}: sensors[2].link: expected a string, got :base_link",
               "#{path}:#{at(source, 7, "\"base_scan")}: sensors[1].link: sensor :laser takes its pose from URDF link \"base_scan\", but the robot has no urdf: file"
             ]
    end

    test "with urdf: a differential drive's wheel geometry may come from the URDF", %{
      tmp_dir: dir
    } do
      File.mkdir_p!(Path.join(dir, "urdf"))
      write(Path.join(dir, "urdf"), "r.urdf", "<robot name=\"r\"/>")

      source = """
      [
        name: "r",
        urdf: "urdf/r.urdf",
        footprint: [radius: 0.2],
        kinematics: [type: :differential],
        sensors: [[name: :laser, type: :laser, range: {0.1, 5}, fov: 3, beams: 9, link: "scan"]]
      ]
      """

      assert {:ok, %RDF{} = rdf} = Config.read(write(dir, "urdf.rdf", source))
      assert rdf.urdf == Path.join(dir, "urdf/r.urdf")
      assert %{wheel_radius: nil, wheel_separation: nil} = rdf.kinematics
      assert [%{link: "scan", crosstalk: false, pose: {0.0, 0.0, 0.0}}] = rdf.sensors

      # without urdf: the geometry is required; a car-like drive always needs its own
      no_urdf = String.replace(source, ~s(  urdf: "urdf/r.urdf",\n), "")
      path = write(dir, "no_urdf.rdf", no_urdf)

      assert [radius, separation, _link] = errors(path)
      assert radius =~ "#{path}:4:15: kinematics: a differential drive needs wheel_radius:"

      assert separation =~
               "#{path}:4:15: kinematics: a differential drive needs wheel_separation:"

      car = String.replace(source, "type: :differential", "type: :tricycle")
      path = write(dir, "car.rdf", car)
      assert [wheelbase, steering] = errors(path)
      assert wheelbase =~ "#{path}:5:15: kinematics: a tricycle drive needs wheelbase:"
      assert steering =~ "needs max_steering:"

      # the URDF must exist
      missing = String.replace(source, "urdf/r.urdf", "urdf/gone.urdf")
      path = write(dir, "missing.rdf", missing)

      assert errors(path) == [
               "#{path}:#{at(missing, 3, "\"urdf/")}: urdf: no such file #{Path.join(dir, "urdf/gone.urdf")}"
             ]
    end

    test "doors connect known places; polygons have 3 points; names are unique", %{tmp_dir: dir} do
      source = """
      [
        name: "w",
        rooms: [[name: :a, polygon: [{0, 0}, {1, 0}]]],
        doors: [[name: :a, from: {0, 0}, to: {1, 0}, connects: [:a, :nowhere]]]
      ]
      """

      path = write(dir, "places.wdf", source)

      assert errors(path) == [
               "#{path}:#{at(source, 4, ":a,")}: doors[0].name: :a is already the name of rooms[0]",
               "#{path}:#{at(source, 3, "[{0")}: rooms[0].polygon: needs at least 3 points",
               "#{path}:#{at(source, 4, ":nowhere")}: doors[0].connects: :nowhere is not a room or corridor of this world"
             ]
    end
  end

  describe "files" do
    test "unknown extensions and unreadable files are errors, not crashes", %{tmp_dir: dir} do
      assert [error] = errors(write(dir, "robot.toml", "[]"))

      assert error =~
               "robot.toml:0:0: unknown kind of file: expected a .adf, .rdf or .wdf description file"

      assert [error] = errors(Path.join(dir, "absent.adf"))
      assert error =~ "absent.adf:0:0: cannot read the file: no such file or directory"
    end
  end
end
