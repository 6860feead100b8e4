defmodule ThinkingCap.Robot.DescriptionTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Robot.Kinematics.{Differential, Tricycle}

  @turtlebot Path.expand("../../../../../test/data/turtlebot3_burger.urdf", __DIR__)
  @examples Path.expand("../../../../../priv/examples", __DIR__)

  @moduletag :tmp_dir

  defp write(dir, name, text) do
    path = Path.join(dir, name)
    File.write!(path, text)
    path
  end

  # `target` relative to `dir` (both absolute): "../../test/data/..."
  defp relative(target, dir) do
    {t, d} = {Path.split(target), Path.split(dir)}
    common = Enum.zip(t, d) |> Enum.take_while(fn {a, b} -> a == b end) |> length()
    Path.join(List.duplicate("..", length(d) - common) ++ Enum.drop(t, common))
  end

  defp turtlebot_rdf(dir, opts \\ []) do
    urdf = Keyword.get(opts, :urdf, relative(@turtlebot, dir))

    write(dir, Keyword.get(opts, :name, "burger.rdf"), """
    [
      name: "burger",
      urdf: #{inspect(urdf)},
      footprint: [radius: 0.105],
      kinematics: [type: :differential, max_speed: 0.22#{opts[:kinematics]}],
      odometry_error: [slip: 0.01],
      sensors: [
        [name: :laser, type: :laser, link: #{inspect(Keyword.get(opts, :link, "base_scan"))},
         range: {0.12, 3.5}, fov: 6.28, beams: 360],
        [name: :sonar, type: :sonar, pose: {0.1, 0.0, 0.0}, range: {0.02, 2}, fov: 0.3,
         crosstalk: true],
        [name: :odom, type: :odometry]
      ]
    ]
    """)
  end

  test "the TurtleBot: wheel geometry and the laser's pose come from the URDF", %{tmp_dir: dir} do
    path = turtlebot_rdf(dir)
    # the urdf: is relative to the RDF
    assert File.read!(path) =~ ~s(urdf: "../)
    assert {:ok, %Description{} = d} = Description.load(path)

    assert d.name == "burger"
    assert d.file == path
    assert d.footprint == %{radius: 0.105, polygon: nil}
    assert d.urdf.name == "turtlebot3_burger"

    assert %Differential{wheel_radius: r, wheel_separation: b, max_speed: 0.22} = d.kinematics
    assert_in_delta r, 0.033, 1.0e-12
    assert_in_delta b, 0.160, 1.0e-12

    assert %{slip: 0.01, wheel_diameter_ratio: 1.0} = d.odometry_error

    assert [laser, sonar, odom] = d.sensors
    assert %{name: :laser, link: "base_scan", range: {0.12, 3.5}} = laser
    {x, y, yaw} = laser.pose
    assert_in_delta x, -0.032, 1.0e-12
    assert_in_delta y, 0.0, 1.0e-12
    assert_in_delta yaw, 0.0, 1.0e-12
    # sensors without link: keep the RDF's pose
    assert %{pose: {0.1, 0.0, 0.0}, crosstalk: true, link: nil} = sensor = sonar
    assert sensor.count == 1
    assert %{pose: {0.0, 0.0, 0.0}, crosstalk: false} = odom
  end

  test "an absolute urdf: path works as well; the RDF's wheel geometry wins over the URDF's", %{
    tmp_dir: dir
  } do
    path = turtlebot_rdf(dir, urdf: @turtlebot, kinematics: ", wheel_radius: 0.035")
    assert {:ok, d} = Description.load(path)
    assert d.kinematics.wheel_radius == 0.035
    assert_in_delta d.kinematics.wheel_separation, 0.160, 1.0e-12
  end

  test "a polygon footprint has its circumscribed radius; no URDF, no change", %{tmp_dir: dir} do
    path =
      write(dir, "cart.rdf", """
      [
        name: "cart",
        footprint: [polygon: [{0.6, 0.3}, {-0.2, 0.3}, {-0.2, -0.3}, {0.6, -0.3}]],
        kinematics: [type: :tricycle, wheelbase: 0.8, max_steering: 1.5],
        sensors: [[name: :front, type: :laser, pose: {0.6, 0, 0}, range: {0.1, 10}, fov: 3, beams: 10]]
      ]
      """)

    assert {:ok, d} = Description.load(path)
    assert_in_delta d.footprint.radius, :math.sqrt(0.45), 1.0e-12
    assert length(d.footprint.polygon) == 4
    assert %Tricycle{wheelbase: 0.8} = d.kinematics
    assert d.urdf == nil
    assert [%{pose: {0.6, 0.0, 0.0}}] = d.sensors
  end

  test "the office example loads", _ do
    assert {:ok, d} = Description.load(Path.join(@examples, "office_robot.rdf"))

    assert %Differential{wheel_radius: 0.033, wheel_separation: 0.16, max_speed: 0.4} =
             d.kinematics

    assert d.footprint.radius == 0.2
    assert d.odometry_error.wheelbase_ratio == 0.995
    assert length(d.sensors) == 5
  end

  describe "errors" do
    test "a link the URDF lacks names the RDF, the sensor and the URDF", %{tmp_dir: dir} do
      path = turtlebot_rdf(dir, link: "base_laser")
      assert {:error, message} = Description.load(path)

      assert message =~
               "#{path}: sensor :laser: link: #{@turtlebot}: no link named \"base_laser\" (links: "
    end

    test "a broken URDF names both files", %{tmp_dir: dir} do
      write(dir, "broken.urdf", "<robot name=\"b\"><link name=\"base_link\">\n</robot>")
      path = turtlebot_rdf(dir, urdf: "broken.urdf")
      assert {:error, message} = Description.load(path)
      assert message =~ "#{path}: urdf:\n#{Path.join(dir, "broken.urdf")}:2:0: malformed XML"
    end

    test "a URDF without two wheels cannot give the wheel geometry", %{tmp_dir: dir} do
      write(dir, "nowheels.urdf", ~s(<robot name="n"><link name="base_link"/></robot>))
      path = turtlebot_rdf(dir, urdf: "nowheels.urdf", link: "base_link")
      assert {:error, message} = Description.load(path)

      assert message =~
               "#{path}: kinematics: no wheel_radius/wheel_separation, and #{Path.join(dir, "nowheels.urdf")}: expected two continuous wheel joints"
    end

    test "an invalid RDF gives the reader's file:line:column errors", %{tmp_dir: dir} do
      path = write(dir, "bad.rdf", "[name: \"x\", footprint: [radius: 0.1],\n kinematics: 3]")
      assert {:error, message} = Description.load(path)
      assert message =~ "#{path}:2:14: kinematics: expected a keyword list"

      assert {:error, message} = Description.load(Path.join(@examples, "office.wdf"))
      assert message =~ "office.wdf: not a robot description"
    end

    test "from_rdf/1 takes a read RDF", %{tmp_dir: dir} do
      {:ok, rdf} = Config.read(turtlebot_rdf(dir))
      assert {:ok, %Description{name: "burger"}} = Description.from_rdf(rdf)
      assert {:error, message} = Description.from_rdf(%{rdf | urdf: Path.join(dir, "gone.urdf")})
      assert message =~ "urdf:\n#{Path.join(dir, "gone.urdf")}:0:0: cannot read the URDF"
    end
  end
end
