defmodule ThinkingCap.Testing.Sim do
  @moduledoc """
  Test worlds and test robots for the simulator: description data written
  to real `.wdf`/`.rdf` files (so they go through the same reader and
  checks as a user's) and loaded.

      world = ThinkingCap.Testing.Sim.world!(dir, walls: ThinkingCap.Testing.Sim.box(10, 10))
      robot = ThinkingCap.Testing.Sim.robot!(dir, sensors: [[name: :laser, type: :laser, ...]])
      {:ok, sim} = ThinkingCap.Sim.start_link(world: world, mode: :fast, running: false)

  `robot!/2` fills a small differential robot (radius 0.2 m, no
  odometry error) around what it is given.
  """

  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim.World

  @doc "The four walls of an axis-aligned box from `{0, 0}` to `{w, h}`."
  @spec box(number(), number()) :: [{{number(), number()}, {number(), number()}}]
  def box(w, h),
    do: [{{0, 0}, {w, 0}}, {{w, 0}, {w, h}}, {{w, h}, {0, h}}, {{0, h}, {0, 0}}]

  @doc "Writes WDF data (a keyword list, `name:` defaulted) to `dir` and builds its world."
  @spec world!(Path.t(), keyword()) :: World.t()
  def world!(dir, data) do
    path = write!(dir, "world", "wdf", Keyword.put_new(data, :name, "test world"))
    {:ok, world} = World.load(path)
    world
  end

  @doc "The path of a WDF written from `data` into `dir`."
  @spec wdf!(Path.t(), keyword()) :: Path.t()
  def wdf!(dir, data), do: write!(dir, "world", "wdf", Keyword.put_new(data, :name, "test world"))

  @doc "Writes RDF data, completed with a small differential robot's, and loads it."
  @spec robot!(Path.t(), keyword()) :: Description.t()
  def robot!(dir, data \\ []) do
    {:ok, description} = Description.load(rdf!(dir, data))
    description
  end

  @doc "The path of an RDF written from `data` (completed as in `robot!/2`) into `dir`."
  @spec rdf!(Path.t(), keyword()) :: Path.t()
  def rdf!(dir, data \\ []) do
    data =
      [
        name: "test robot",
        footprint: [radius: 0.2],
        kinematics: [
          type: :differential,
          wheel_radius: 0.05,
          wheel_separation: 0.3,
          max_speed: 1.0,
          max_turn_rate: 2.0,
          max_acceleration: 10.0
        ]
      ]
      |> Keyword.merge(data)

    write!(dir, "robot", "rdf", data)
  end

  defp write!(dir, base, ext, data) do
    File.mkdir_p!(dir)
    path = Path.join(dir, "#{base}_#{System.unique_integer([:positive])}.#{ext}")
    File.write!(path, inspect(data, limit: :infinity, printable_limit: :infinity) <> "\n")
    path
  end
end
