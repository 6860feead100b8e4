defmodule ThinkingCap.Robot.URDFTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Robot.URDF
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @turtlebot Path.expand("../../../../../test/data/turtlebot3_burger.urdf", __DIR__)
  @pi :math.pi()

  @moduletag :tmp_dir

  defp write(dir, name, text) do
    path = Path.join(dir, name)
    File.write!(path, text)
    path
  end

  # positions compared as numbers, angles on the circle (π and −π are one yaw)
  defp assert_pose({:ok, {x, y, z, _, _, _} = pose}, expected) do
    {ex, ey, ez, _, _, _} = expected
    assert_in_delta x, ex, 1.0e-9
    assert_in_delta y, ey, 1.0e-9
    assert_in_delta z, ez, 1.0e-9

    for i <- 3..5,
        do:
          assert_in_delta(
            normalize_angle(elem(pose, i) - elem(expected, i)),
            0.0,
            1.0e-9
          )
  end

  # a URDF of fixed joints: {name, parent, child, "x y z", "r p y"}
  defp chain(dir, joints) do
    links = joints |> Enum.flat_map(fn {_, p, c, _, _} -> [p, c] end) |> Enum.uniq()

    write(dir, "chain.urdf", """
    <?xml version="1.0"?>
    <robot name="chain">
      #{Enum.map_join(links, "\n  ", &~s(<link name="#{&1}"/>))}
      #{Enum.map_join(joints, "\n  ", fn {n, p, c, xyz, rpy} -> ~s(<joint name="#{n}" type="fixed"><parent link="#{p}"/><child link="#{c}"/><origin xyz="#{xyz}" rpy="#{rpy}"/></joint>) end)}
    </robot>
    """)
  end

  describe "the TurtleBot 3 Burger" do
    setup do
      {:ok, urdf} = URDF.load(@turtlebot)
      %{urdf: urdf}
    end

    test "links, joints and their geometry", %{urdf: urdf} do
      assert urdf.name == "turtlebot3_burger"

      assert urdf.links |> Map.keys() |> Enum.sort() ==
               ~w(base_footprint base_link base_scan caster_back_link imu_link wheel_left_link wheel_right_link)

      assert %{type: :continuous, parent: "base_link", child: "wheel_left_link"} =
               joint = urdf.joints["wheel_left_joint"]

      assert joint.origin == {{0.0, 0.08, 0.023}, {-1.57, 0.0, 0.0}}
      assert joint.axis == {0.0, 0.0, 1.0}
      assert urdf.joints["scan_joint"].type == :fixed

      assert [%{type: :cylinder, radius: 0.033, length: 0.018}] =
               urdf.links["wheel_left_link"].collision

      assert [%{type: :mesh, scale: {0.001, 0.001, 0.001}, filename: "package://" <> _}] =
               urdf.links["wheel_left_link"].visual

      assert [%{type: :box, size: {0.14, 0.14, 0.143}, origin: {{-0.032, +0.0, 0.07}, _}}] =
               urdf.links["base_link"].collision
    end

    test "base_scan is at (−0.032, 0, 0.172) from base_link", %{urdf: urdf} do
      assert_pose(URDF.pose(urdf, "base_scan"), {-0.032, 0.0, 0.172, 0.0, 0.0, 0.0})
      assert_pose(URDF.pose(urdf, "base_scan", "base_link"), {-0.032, 0.0, 0.172, 0.0, 0.0, 0.0})
      # through two joints from the root
      assert_pose(URDF.pose(urdf, "base_scan", "base_footprint"), {-0.032, 0.0, 0.182, 0, 0, 0})
      # up the tree: the root seen from base_link
      assert_pose(URDF.pose(urdf, "base_footprint"), {0.0, 0.0, -0.01, 0.0, 0.0, 0.0})
      # across the tree: the laser seen from the IMU
      assert_pose(URDF.pose(urdf, "base_scan", "imu_link"), {0.0, 0.0, 0.104, 0.0, 0.0, 0.0})
      # a wheel's frame is rolled −1.57 rad (its axis z points along −y... almost)
      assert_pose(URDF.pose(urdf, "wheel_right_link"), {0.0, -0.08, 0.023, -1.57, 0.0, 0.0})
      assert_pose(URDF.pose(urdf, "base_link", "base_link"), {0, 0, 0, 0, 0, 0})
    end

    test "its wheels: separation 0.160 m, radius 0.033 m", %{urdf: urdf} do
      assert {:ok, %{separation: separation, radius: radius}} = URDF.wheels(urdf)
      assert_in_delta separation, 0.160, 1.0e-12
      assert_in_delta radius, 0.033, 1.0e-12
    end

    test "an unknown link is an error naming the file and the links there are", %{urdf: urdf} do
      assert {:error, message} = URDF.pose(urdf, "laser")
      assert message =~ "#{@turtlebot}: no link named \"laser\" (links: base_footprint, base_link"
      assert {:error, message} = URDF.pose(urdf, "base_scan", "chassis")
      assert message =~ "no link named \"chassis\""
    end
  end

  describe "composing 3-D rotations" do
    test "yaw then translation", %{tmp_dir: dir} do
      path =
        chain(dir, [
          {"j1", "base_link", "a", "1 0 0", "0 0 #{@pi / 2}"},
          {"j2", "a", "b", "1 0 0", "0 0 #{@pi / 2}"}
        ])

      {:ok, urdf} = URDF.load(path)
      # a is turned left by 90°, so b's offset along a's x is along base y
      assert_pose(URDF.pose(urdf, "b"), {1.0, 1.0, 0.0, 0.0, 0.0, @pi})
      # and back: base_link seen from b
      assert_pose(URDF.pose(urdf, "base_link", "b"), {1.0, 1.0, 0.0, 0.0, 0.0, -@pi})
    end

    test "roll and pitch move offsets out of the plane", %{tmp_dir: dir} do
      path =
        chain(dir, [
          {"j1", "base_link", "a", "0 0 0", "#{@pi / 2} 0 0"},
          {"j2", "a", "b", "0 1 0", "0 0 0"},
          {"j3", "b", "c", "0 0 0", "0 #{@pi / 2} 0"},
          {"j4", "c", "d", "0 0 2", "0 0 0"},
          {"j5", "base_link", "e", ".5 0 -.25", "0.1 0.2 0.3"}
        ])

      {:ok, urdf} = URDF.load(path)
      # rolled 90° about x, a's y axis is base's z
      assert_pose(URDF.pose(urdf, "b"), {0.0, 0.0, 1.0, @pi / 2, 0.0, 0.0})

      # pitched 90° in a rolled frame: c's z axis (Rx(90°) Ry(90°) ẑ) = base's x
      {:ok, {x, y, z, _, _, _}} = URDF.pose(urdf, "d")
      assert_in_delta x, 2.0, 1.0e-9
      assert_in_delta y, 0.0, 1.0e-9
      assert_in_delta z, 1.0, 1.0e-9

      # a general rotation survives the round trip through the matrix
      assert_pose(URDF.pose(urdf, "e"), {0.5, 0.0, -0.25, 0.1, 0.2, 0.3})
    end
  end

  describe "errors" do
    # load's errors, as `file:line:column: message` strings
    defp errors(path) do
      assert {:error, [_ | _] = errors} = URDF.load(path)
      Enum.map(errors, &to_string/1)
    end

    test "a missing file", %{tmp_dir: dir} do
      path = Path.join(dir, "absent.urdf")
      assert errors(path) == ["#{path}:0:0: cannot read the URDF: no such file or directory"]
    end

    test "malformed XML names the file and line", %{tmp_dir: dir} do
      path = write(dir, "bad.urdf", ~s(<robot name="r">\n  <link name="a">\n</robot>\n))

      assert errors(path) == [
               "#{path}:3:0: malformed XML: </robot> closes <link> (opened at line 2)"
             ]

      path = write(dir, "two.urdf", ~s(<robot name="a"><link name="l"/></robot><robot/>))
      assert errors(path) == ["#{path}:1:0: malformed XML: content after the root element"]
      # comments may follow the root
      assert {:ok, _} =
               URDF.load(
                 write(dir, "c.urdf", ~s(<robot><link name="l"/></robot>\n<!-- end -->\n))
               )

      path = write(dir, "empty.urdf", "")
      assert errors(path) == ["#{path}:1:0: malformed XML: no root element"]
    end

    test "not a robot, a joint to nowhere, a bad number, a loop, no wheels", %{tmp_dir: dir} do
      path = write(dir, "sdf.urdf", ~s(<sdf version="1.6"><model name="m"/></sdf>))

      assert errors(path) == [
               "#{path}:1:0: not a URDF: the root element is <sdf>, expected <robot>"
             ]

      path =
        write(dir, "dangling.urdf", """
        <robot name="r">
          <link name="base_link"/>
          <joint name="j" type="fixed"><parent link="base_link"/><child link="ghost"/></joint>
        </robot>
        """)

      assert errors(path) == ["#{path}:3:0: joint \"j\" names an unknown link \"ghost\""]

      path =
        write(dir, "number.urdf", """
        <robot name="r">
          <link name="base_link"/><link name="a"/>
          <joint name="j" type="fixed"><parent link="base_link"/><child link="a"/>
            <origin xyz="0 zero 0"/></joint>
        </robot>
        """)

      assert errors(path) == [
               "#{path}:3:0: joint \"j\" origin: xyz= expected 3 numbers, got \"0 zero 0\""
             ]

      path =
        write(dir, "type.urdf", """
        <robot name="r"><link name="a"/><link name="b"/>
          <joint name="j" type="hinge"><parent link="a"/><child link="b"/></joint></robot>
        """)

      assert [message] = errors(path)
      assert message =~ "#{path}:2:0: joint \"j\": unknown type \"hinge\""

      path = chain(dir, [{"j1", "a", "b", "0 0 0", "0 0 0"}, {"j2", "b", "a", "0 0 0", "0 0 0"}])
      assert [message] = errors(path)
      assert message =~ "#{path}:3:0: the joints form a loop through link"

      {:ok, urdf} = URDF.load(chain(dir, [{"j", "base_link", "a", "0 0 0", "0 0 0"}]))
      assert {:error, message} = URDF.wheels(urdf)

      assert message =~
               "chain.urdf: expected two continuous wheel joints (named *wheel*, their links with a cylinder), found 0"
    end

    test "every bad link and joint at once, at its line, twice-given names too", %{tmp_dir: dir} do
      path =
        write(dir, "many.urdf", """
        <robot name="r">
          <link name="a"/>
          <link/>
          <link name="a"/>
          <joint name="j" type="fixed"><parent link="a"/></joint>
          <link name="b"><visual><geometry><sphere radius="big"/></geometry></visual></link>
        </robot>
        """)

      assert errors(path) == [
               "#{path}:3:0: a <link> without a name",
               "#{path}:4:0: link \"a\" is given twice (first at line 2)",
               "#{path}:5:0: joint \"j\" has no <child link=\"...\"/>",
               "#{path}:6:0: link \"b\" <visual> sphere: radius= expected a number, got \"big\""
             ]
    end
  end
end
