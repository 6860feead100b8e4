defmodule ThinkingCap.Navigation.TopologyTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config.WDF
  alias ThinkingCap.Navigation.Topology

  @office Path.expand("../../../../../priv/examples/office.wdf", __DIR__)

  setup_all do
    wdf = ThinkingCap.Config.read!(@office)
    %{wdf: wdf, topo: Topology.from_wdf(wdf)}
  end

  test "places are the rooms and corridors, with their centroids", %{topo: topo} do
    assert topo.places |> Map.keys() |> Enum.sort() == [:hall, :lab, :office_a, :office_b]
    assert topo.places.lab.centroid == {3.5, 6.5}
    assert topo.places.hall.centroid == {10.0, 1.5}
    assert topo.places.hall.kind == :corridor
    assert topo.doors.a_door.centre == {9.5, 3.0}
    assert Enum.sort(topo.doors.a_door.connects) == [:hall, :office_a]
  end

  test "place_of/2: inside a polygon, else the nearest centroid", %{topo: topo} do
    assert Topology.place_of(topo, {10.0, 1.0}) == :hall
    assert Topology.place_of(topo, {10.0, 5.0}) == :office_a
    assert Topology.place_of(topo, {1.0, 9.0}) == :lab
    # on the wall between the hall and office_b: rooms first
    assert Topology.place_of(topo, {16.0, 3.0}) == :office_b
    # outside the building, east
    assert Topology.place_of(topo, {25.0, 6.0}) == :office_b
  end

  test "route/4 through the doors", %{topo: topo} do
    assert {:ok, steps} = Topology.route(topo, :lab, :office_a)

    assert steps == [
             %{place: :lab, via_door: nil, point: {3.5, 6.5}},
             %{place: :hall, via_door: :lab_door, point: {3.0, 3.0}},
             %{place: :office_a, via_door: :a_door, point: {9.5, 3.0}}
           ]

    assert {:ok, [%{place: :hall, via_door: nil}]} = Topology.route(topo, :hall, :hall)

    # from a point to a point
    assert {:ok, [%{place: :hall, point: {18.0, 1.0}}, %{place: :lab, via_door: :lab_door}]} =
             Topology.route(topo, {18.0, 1.0}, {1.0, 8.0})
  end

  test "b_door is closed at start: office_b has no route until it opens", %{topo: topo} do
    assert {:error, :no_route} = Topology.route(topo, :hall, :office_b)
    assert {:error, :no_route} = Topology.route(topo, :lab, :office_b, closed: [:b_door])

    assert {:ok, steps} = Topology.route(topo, :lab, :office_b, closed: [])
    assert Enum.map(steps, & &1.via_door) == [nil, :lab_door, :b_door]
    assert List.last(steps) == %{place: :office_b, via_door: :b_door, point: {16.0, 3.0}}

    # closing another door instead
    assert {:error, :no_route} = Topology.route(topo, :hall, :office_a, closed: [:a_door])
    assert {:error, :no_route} = Topology.route(topo, :hall, :nowhere)
    assert Topology.neighbours(topo, :hall) |> Enum.sort() == [lab: :lab_door, office_a: :a_door]
  end

  test "doors without connects join the places on either side", %{wdf: wdf, topo: topo} do
    bare = Topology.from_wdf(%{wdf | doors: Enum.map(wdf.doors, &%{&1 | connects: []})})

    for {name, door} <- topo.doors,
        do: assert(Enum.sort(bare.doors[name].connects) == Enum.sort(door.connects))
  end

  # four rooms in a square; two ways round, of different lengths
  defp square_of_rooms do
    room = fn name, x, y ->
      %{name: name, polygon: [{x, y}, {x + 5.0, y}, {x + 5.0, y + 5.0}, {x, y + 5.0}]}
    end

    door = fn name, from, to -> %{name: name, from: from, to: to, open: true, connects: []} end

    %WDF{
      name: "square",
      rooms: [
        room.(:sw, 0.0, 0.0),
        room.(:se, 5.0, 0.0),
        room.(:nw, 0.0, 5.0),
        room.(:ne, 5.0, 5.0)
      ],
      doors: [
        door.(:sw_se, {5.0, 3.5}, {5.0, 4.5}),
        door.(:se_ne, {5.5, 5.0}, {6.5, 5.0}),
        door.(:sw_nw, {0.5, 5.0}, {1.5, 5.0}),
        door.(:nw_ne, {5.0, 8.5}, {5.0, 9.5})
      ]
    }
  end

  test "route/4 takes the shorter way round, and the other when a door closes" do
    topo = Topology.from_wdf(square_of_rooms())
    assert Enum.sort(topo.doors.nw_ne.connects) == [:ne, :nw]

    # via se: 2.92 + 1.41 + 2.92 m; via nw: 2.92 + 5.66 + 2.92 m
    assert {:ok, steps} = Topology.route(topo, :sw, :ne)
    assert Enum.map(steps, & &1.place) == [:sw, :se, :ne]

    assert {:ok, steps} = Topology.route(topo, :sw, :ne, closed: [:se_ne])
    assert Enum.map(steps, & &1.via_door) == [nil, :sw_nw, :nw_ne]

    # starting next to the west door makes the way by nw the shorter
    assert {:ok, steps} =
             Topology.route(topo, :sw, :ne, from_point: {1.0, 4.9}, to_point: {5.5, 9.0})

    assert Enum.map(steps, & &1.place) == [:sw, :nw, :ne]
  end
end
